"""Fuse: orthogonal stereo association of horizontal and vertical features (paper Sec. IV.B).

Per keyframe, `stages.kernels.fusion.fuse_keyframe` (shared with stage `submaps`):
overlap, subproblems per range bin with the cost of Eq. 5 and the confidence of Eq. 6,
and the Eq. 3 point. This module holds the config section and the `fused.parquet` table.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from pydantic import Field, model_validator

from schemas.fused import FUSED_SCHEMA
from schemas.sensors import Sensors
from schemas.sonar import KeyframeImages
from stages.base import Input, Output, Stage, StageConfig
from stages.kernels.association import ConfidenceRule
from stages.kernels.fusion import fuse_keyframe, sonar_offset

__all__ = ["STAGE", "FuseConfig", "fuse_table"]


class FuseConfig(StageConfig):
    """Config section `fuse`.

    Attributes:
        patch_size_px: side of the square patch of Eq. 5 (odd) [pixels].
        horizontal_aperture_deg: vertical extent of the horizontal sonar's beams [deg].
        vertical_aperture_deg: horizontal extent of the vertical sonar's beams [deg].
        min_confidence: associations with confidence below this are culled (-1: none).
        rotate_vertical_patch: rotate the vertical patch 90 deg before comparing (paper).
        min_subproblem_features: smallest horizontal and vertical set of a solved range bin.
        confidence_rule: "paper" (Eq. 6) or "ratio" (the original code's; module docstring).
        max_cost_ratio: ratio rule only: keep associations with L_ij / L_2 below this.
    """

    patch_size_px: int = Field(5, ge=1, le=63)
    horizontal_aperture_deg: float = Field(20.0, gt=0.0, lt=180.0)
    vertical_aperture_deg: float = Field(20.0, gt=0.0, lt=180.0)
    min_confidence: float = Field(-1.0, ge=-1.0, le=1.0)
    rotate_vertical_patch: bool = True
    min_subproblem_features: int = Field(
        1,
        ge=1,
        le=100000,
        description="a range-bin subproblem is solved only if both its horizontal and its"
        " vertical set have at least this many features (1: every bin; original code: 3)",
    )
    confidence_rule: ConfidenceRule = Field(
        "paper",
        description="'paper': Eq. 6, (L_2 - L_ij) / sum L; 'ratio': rho = L_ij / L_2 of the"
        " bin's smaller-set feature, the original code's per-feature cost ratio, stored as"
        " confidence (1 - rho) / (1 + rho)",
    )
    max_cost_ratio: float | None = Field(
        None,
        gt=0.0,
        le=1.0,
        description="with confidence_rule 'ratio', keep associations whose cost ratio"
        " L_ij / L_2 is below this (None: keep all; original code 0.97 sim, 0.98 real)",
    )

    @model_validator(mode="after")
    def _ratio_cut_needs_ratio_rule(self) -> FuseConfig:
        if self.max_cost_ratio is not None and self.confidence_rule != "ratio":
            raise ValueError("max_cost_ratio needs confidence_rule 'ratio'")
        return self


_FEATURE_COLUMNS = (
    "keyframe_id",
    "feature_id",
    "sonar",
    "range_bin",
    "beam",
    "range_m",
    "angle_rad",
)


def _feature_arrays(features: pa.Table) -> dict[str, np.ndarray]:
    """Feature columns as numpy, sorted by (keyframe_id, feature_id), `sonar` as a bool
    `is_horizontal`."""
    missing = [c for c in _FEATURE_COLUMNS if c not in features.column_names]
    if missing:
        raise ValueError(f"fuse: features table lacks columns {missing}")
    cols = {c: features.column(c).to_numpy() for c in _FEATURE_COLUMNS if c != "sonar"}
    is_h = pc.equal(features.column("sonar"), "horizontal")
    cols["is_horizontal"] = is_h.to_numpy(zero_copy_only=False).astype(bool)
    kf, fid = cols["keyframe_id"], cols["feature_id"]
    ordered = len(kf) < 2 or bool(
        np.all((kf[1:] > kf[:-1]) | ((kf[1:] == kf[:-1]) & (fid[1:] > fid[:-1])))
    )
    if ordered:
        return cols
    order = np.lexsort((fid, kf))
    return {c: v[order] for c, v in cols.items()}


def fuse_table(
    frames: Sequence[KeyframeImages],
    features: pa.Table,
    sensors: Sensors | Mapping[str, Any],
    config: FuseConfig,
) -> pa.Table:
    """`fused.parquet` for all keyframes (one keyframe's images in memory at a time)."""
    T_h_v = sonar_offset(sensors)
    cols = _feature_arrays(features)
    kf = cols["keyframe_id"]
    chunks: list[dict[str, np.ndarray]] = []
    for frame in frames:
        lo, hi = np.searchsorted(kf, [frame.keyframe_id, frame.keyframe_id + 1])
        if hi == lo:
            continue
        part = fuse_keyframe(frame, {c: v[lo:hi] for c, v in cols.items()}, T_h_v, config)
        part["keyframe_id"] = np.full(len(part["range_m"]), frame.keyframe_id, np.int64)
        chunks.append(part)
    if not chunks:
        return FUSED_SCHEMA.empty_table()
    arrays = [pa.array(np.concatenate([c[f.name] for c in chunks])) for f in FUSED_SCHEMA]
    return pa.Table.from_arrays(arrays, schema=FUSED_SCHEMA)


def run(config: FuseConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    """Stage entry point: keyframes.frames, keyframes.sensors, features.features -> fused."""
    table = fuse_table(
        inputs["keyframes.frames"], inputs["features.features"], inputs["keyframes.sensors"], config
    )
    return {"fused": table}


STAGE = Stage(
    name="fuse",
    version=1,
    config=FuseConfig,
    inputs=(
        Input("keyframes", "frames"),
        Input("keyframes", "sensors"),
        Input("features", "features"),
    ),
    outputs=(Output("fused", "parquet", "fused.parquet", schema=FUSED_SCHEMA),),
    run=run,
    description="orthogonal stereo association of horizontal and vertical features (Eq. 3, 5, 6)",
)
