"""Config section `classify` (imports no numpy or pyarrow: planning reads it)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from sonarmap.stages.classify.model_choice import ModelChoice

__all__ = ["RASTER_VERSION", "ClassifyConfig"]

RASTER_VERSION = 1
"""Version of `sonarmap.stages.classify.annotations`' rasterisation of labelled objects: bumped
whenever it could label a cell differently (it enters the train key, which planning
computes, hence here)."""


class ClassifyConfig(ModelChoice):
    """DBSCAN clustering and MC-dropout acceptance (paper Sec. IV.C).

    The clustering defaults live once, in `sonarmap.stages.classify.train.TrainConfig`: a model is trained
    on the objects its clustering produces, so classify reads them from the model file
    and these fields only override them (an override outside what the model saw in
    training changes what it is shown).
    """

    eps_m: float | None = Field(
        None, gt=0, le=100, description="DBSCAN radius [m]; None: the model's (train.eps_m)"
    )
    min_samples: int | None = Field(
        None,
        ge=1,
        le=100000,
        description="DBSCAN core neighbourhood; None: the model's (train.min_samples)",
    )
    min_features: int | None = Field(
        None,
        ge=1,
        le=100000,
        description="smallest object kept; None: the model's (train.min_features)",
    )
    min_object_area_m2: float | None = Field(
        None,
        gt=0,
        le=10000,
        description="keep only objects whose feature cells cover more than this fan-plane"
        " area (sonarmap.stages.classify.segmentation.cell_areas_m2; None: no area rule; original sim code:"
        " > 150 px of 5 cm = 0.375 m2); not applied in training",
    )
    drop_fan_edge_objects: bool = Field(
        False,
        description="drop objects whose padded bounding box reaches outside the horizontal"
        " sonar's fan (sonarmap.stages.classify.segmentation.fan_outside_area_m2; original sim code); dropped"
        " objects are not in objects.parquet",
    )
    fan_edge_margin_m: float = Field(
        0.25,
        ge=0,
        le=100,
        description="padding of the fan-edge box on each side [m] (original 5 px)",
    )
    fan_edge_max_outside_m2: float = Field(
        0.025,
        gt=0,
        le=10000,
        description="an object is dropped when this much of its padded box lies outside the"
        " fan [m2] (original: 10 px of 5 cm)",
    )
    labels: Literal["cnn", "ground_truth"] = Field(
        "cnn",
        description="'cnn': the classifier (paper Sec. IV.C); 'ground_truth': an oracle"
        " ablation, every object takes the majority class of its returns in the recording's"
        " label images (simulated data only; a class the model has no output for, such as"
        " 'none', becomes unknown)",
    )
    mc_passes: int = Field(20, ge=1, le=1000, description="Monte-Carlo dropout passes m")
    threshold: float = Field(0.99, ge=0, le=1, description="accept when mean probability > this")
    seed: int = Field(
        0, ge=0, le=2**32 - 1, description="dropout-mask seed (combined with keyframe_id)"
    )
    pool_views: bool = Field(
        True,
        description="decide on the class distribution log-linearly pooled over sightings of"
        " the same place in nearby keyframes (sonarmap.stages.classify.view_pooling; not in the paper)",
    )
    pool_radius_m: float = Field(
        0.7, gt=0, le=1000, description="sightings within this in the world are one object"
    )
    pool_window_m: float = Field(
        80.0,
        ge=0,
        le=100000,
        description="... when at most this far apart along the track (DR drift)",
    )
    pool_range_scale_m: float | None = Field(
        15.0,
        gt=0,
        le=10000,
        description="range r_s of a sighting's weight 1/(1+(r/r_s)^4); None: equal",
    )
    min_views: int = Field(
        2,
        ge=1,
        le=1000,
        description="accept a compact class (frame_kind object: a piling) only where at least"
        " this many sightings of its place are pooled (pool_views): a cluster no other"
        " keyframe sees again is no fixed object (the grain's own detections, a fish);"
        " 1: off, as it is without pool_views",
    )
    min_seen_share: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="accept a compact class (frame_kind object: a piling) only where its place"
        " was sighted by at least this share of the keyframes whose horizontal fan covered it"
        " within pool_window_m (pool_views): a fixed object is seen more often than not; a"
        " cluster of the grain's own detections, or a part of a hull, is not. 0: off (the"
        " default: docs/classifier.md), as without pool_views",
    )
