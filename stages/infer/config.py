"""Config section `infer` (stage `sonarmap.stages.infer.stage`): classes, frames, grids and bounds."""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Literal

from pydantic import Field, field_validator, model_validator

from sonarmap.schemas.classes import (
    DEFAULT_TABLE,
    UNKNOWN_CLASS,
    ClassTable,
    known_class_names,
)
from sonarmap.stages.base import StageConfig
from sonarmap.stages.kernels.choices import DEFAULT_FRAME_KINDS, FrameKind, UpdateRule

if TYPE_CHECKING:
    from sonarmap.stages.kernels.object_frame import IcpParams

__all__ = ["DEFAULT_CLASSES", "DEFAULT_FRAME_KINDS", "FrameKind", "InferConfig"]

DEFAULT_CLASSES: tuple[str, ...] = DEFAULT_TABLE.inferred
"""The default table's inferred classes (pilings and seawall): the classes whose inferred
median error stays within 1.5x that of their fused points on every scene measured
(docs/decisions/002-default-inferred-classes.md; hulls, trusses and unknown objects again
on procedural worlds: 015-per-object-height-prior.md)."""
DEFAULT_COARSE_FALLBACK_FACTOR = 2
"""Object-frame models answer from cells this many times larger where their own cell
is empty (`CoarseFallbackModel`): 2, the first coarser level, because it adds accurate
piling voxels at the fused points' error (docs/decisions/003-coarse-fallback-factor.md)."""
DEFAULT_BORROW_MIN_EXTENT_M = 8.0
"""Borrowing (`borrowed_models`, `unknown_argmax_classes`, both off by default): an
object takes heights from another class's beam-frame model only if its returns span at
least this long (extended structure, the beam frame's premise); 8 m, and off by default,
from the measurements in docs/decisions/004-borrowed-models-extent.md."""


class InferConfig(StageConfig):
    """Config section `infer`."""

    classes: tuple[str, ...] | None = Field(
        None,
        description="classes with a height model (the paper: the two piling classes); None:"
        " the class table's classes marked `inferred` (cylindrical_piling, rectangular_piling,"
        " seawall)",
    )
    frame_kinds: dict[str, FrameKind] | None = Field(
        None,
        description="reference frame of each class: 'object' (ICP-registered object frame,"
        " paper Sec. IV.D) or 'beam' (per-beam leading-edge frame, stages.kernels.beam_frame);"
        " listed classes override the class table's `frame_kind`; None: the table's",
    )
    unknown_argmax_classes: tuple[str, ...] = Field(
        (),
        description="inferred classes whose model also gives heights to 'unknown' objects"
        " (classifier not confident) whose arg-max class it is; queried, never updated; a"
        " beam-frame class's only to objects of `borrow_min_extent_m`, an object-frame"
        " (piling) class's only to objects that register to its reference (ICP)",
    )
    borrowed_models: dict[str, str] = Field(
        default_factory=dict,
        description="class -> inferred beam-frame class whose model also gives heights to"
        " the objects of that class (which has no model of its own, e.g. {truss: seawall});"
        " queried, never updated",
    )
    borrow_min_extent_m: float = Field(
        DEFAULT_BORROW_MIN_EXTENT_M,
        ge=0.0,
        le=1000.0,
        description="an object borrows a model (borrowed_models, unknown_argmax_classes) only"
        " if the diagonal of its 2D returns' bounding box is at least this long",
    )
    beam_gap_m: float = Field(
        0.3,
        gt=0.0,
        le=100.0,
        description="beam frame: a longer gap along a beam starts another surface",
    )
    beam_cell_m: float = Field(
        0.1, ge=0.001, le=100.0, description="beam frame: model cell along s"
    )
    beam_update_rule: UpdateRule = Field(
        "mixture",
        description="beam frame: 'product' (Eq. 7, one height per cell) or 'mixture'"
        " (Dirichlet counts of the heights a cell returns from; stages.kernels.height_model)",
    )
    beam_range_cell_m: float | None = Field(
        None,
        ge=0.001,
        le=1000.0,
        description="beam frame: cell along the leading-edge range R0 as a second model"
        " axis; None: one profile per class",
    )
    beam_object_prior_m: float | None = Field(
        None,
        ge=0.001,
        le=100.0,
        description="beam frame: std [m] of the per-object height prior, the kernel density"
        " of the object's own fused heights in the same image that multiplies the class"
        " posterior of its 2D-only returns (sonarmap.stages.kernels.object_prior); None: off"
        " (docs/decisions/015-per-object-height-prior.md)",
    )
    beam_object_prior_floor: float = Field(
        0.05,
        ge=0.0,
        le=1000.0,
        description="beam frame: weight added to the per-object height prior everywhere"
        " (its peak is 1)",
    )
    z_min_m: float = Field(
        -4.0, ge=-1000.0, le=0.0, description="lowest height of the z grid (sonar frame)"
    )
    z_max_m: float = Field(4.0, ge=0.0, le=1000.0, description="highest height of the z grid")
    z_step_m: float = Field(0.05, ge=0.001, le=100.0, description="z grid spacing")
    sigma_m: float = Field(
        0.08, ge=0.0001, le=100.0, description="std of the Gaussian height likelihood"
    )
    range_axis: Literal["offset", "height_equivalent"] = Field(
        "height_equivalent", description="model cell axis along range (see _model_coords)"
    )
    range_cell_m: float = Field(0.1, ge=0.001, le=100.0, description="model cell size along range")
    cross_range_cell_m: float = Field(
        0.05, ge=0.001, le=100.0, description="model cell size across range"
    )
    coarse_fallback_factor: int = Field(
        DEFAULT_COARSE_FALLBACK_FACTOR,
        ge=1,
        le=64,
        description="object frames: a query whose cell has no data takes the answer of the"
        " cell this many times larger that contains it"
        " (sonarmap.stages.kernels.fallback_model.CoarseFallbackModel); 1: none (the paper)",
    )
    profile_fallback: bool = Field(
        False,
        description="object frames (with coarse_fallback_factor > 1): a query whose fine and"
        " coarse cells have no data takes the answer of the class's height profile, its"
        " coarse range cells pooled over all cross-range offsets"
        " (sonarmap.stages.kernels.fallback_model); off: docs/decisions/015-per-object-height-prior.md",
    )
    query_model: Literal["online", "final"] = Field(
        "online",
        description="'online': each keyframe is queried right after its update, with the"
        " model as it stands then (the paper, Sec. IV.E); 'final': every keyframe is"
        " queried after the last update, with the models stage `submaps` queries its"
        " frames with, so sightings before a class's first update predict too",
    )
    confidence_threshold: float = Field(
        0.3, ge=0.0, le=1.0, description="min posterior probability of a MAP height"
    )
    confidence_window_m: float = Field(
        0.08,
        ge=0.0,
        le=100.0,
        description="half-width of the interval around a MAP height whose mass is"
        " its posterior probability",
    )
    max_elevation_deg: float = Field(
        10.0, gt=0.0, le=90.0, description="drop predictions outside +-this elevation"
    )
    reference_voxel_m: float = Field(
        0.05, ge=0.001, le=100.0, description="reference cloud voxel size"
    )
    icp_max_correspondence_m: float = Field(
        0.5, gt=0.0, le=1000.0, description="ICP pairing distance"
    )
    icp_max_iterations: int = Field(30, ge=1, le=10000, description="ICP iteration cap")
    icp_min_fitness: float = Field(
        0.6, ge=0.0, le=1.0, description="min fraction of points paired for a good ICP"
    )
    icp_max_rmse_m: float = Field(
        0.15, gt=0.0, le=1000.0, description="max inlier RMSE of a good ICP"
    )
    icp_max_translation_m: float = Field(
        1.5, gt=0.0, le=10000.0, description="max ICP shift from the object-frame alignment"
    )
    icp_max_rotation_deg: float = Field(
        30.0, gt=0.0, le=360.0, description="max ICP rotation from the object-frame alignment"
    )

    @model_validator(mode="after")
    def _z_grid(self) -> InferConfig:
        if self.z_max_m <= self.z_min_m:
            raise ValueError(f"z_max_m ({self.z_max_m}) must exceed z_min_m ({self.z_min_m})")
        return self

    @field_validator("classes")
    @classmethod
    def _known_classes(cls, value: tuple[str, ...] | None) -> tuple[str, ...] | None:
        return value if value is None else known_class_names(value)

    def class_names_used(self) -> dict[str, Iterable[str]]:
        """Every class name this section holds, by field (checked against the class table
        when the config loads, `sonarmap.pipeline.engine.config.load.check_class_names`)."""
        return {
            "classes": self.classes or (),
            "frame_kinds": self.frame_kinds or {},
            "unknown_argmax_classes": self.unknown_argmax_classes,
            "borrowed_models": [*self.borrowed_models, *self.borrowed_models.values()],
        }

    def with_table(self, table: ClassTable) -> InferConfig:
        """This section with `classes` and `frame_kinds` resolved from the class table
        (config section `classes`) and validated together (what the stages read)."""
        table.check(self.class_names_used()["classes"], "infer.classes")
        table.check(self.frame_kinds or {}, "infer.frame_kinds")
        return InferConfig.model_validate(
            {
                **self.model_dump(),
                "classes": table.inferred if self.classes is None else self.classes,
                "frame_kinds": {**table.frame_kinds(), **(self.frame_kinds or {})},
            }
        )

    def _checked_now(self, *names: str) -> bool:
        """Whether names can be judged before the table is known: always once `classes` is
        given; while it is None (the table's), only names of the default table, judged
        against it (the rest are judged by `with_table`, when the config loads)."""
        return self.classes is not None or all(n in DEFAULT_TABLE.assignable for n in names)

    def _classes_or_default(self) -> tuple[str, ...]:
        return DEFAULT_TABLE.inferred if self.classes is None else self.classes

    @model_validator(mode="after")
    def _argmax_classes_are_inferred(self) -> InferConfig:
        classes = self._classes_or_default()
        bad = [c for c in self.unknown_argmax_classes if self._checked_now(c) and c not in classes]
        if bad:
            raise ValueError(f"unknown_argmax_classes {bad}: each must be an inferred class")
        return self

    @model_validator(mode="after")
    def _borrowed_models_are_inferred_beam_classes(self) -> InferConfig:
        classes = self._classes_or_default()
        bad = {
            borrower: lender
            for borrower, lender in self.borrowed_models.items()
            if self._checked_now(borrower, lender)
            and (borrower in classes or lender not in classes or self.frame_kind(lender) != "beam")
        }
        if UNKNOWN_CLASS in self.borrowed_models and self.unknown_argmax_classes:
            raise ValueError(
                "borrowed_models lends 'unknown' a model while unknown_argmax_classes routes"
                " it by arg-max class: set one of them"
            )
        if bad:
            raise ValueError(
                f"borrowed_models {bad}: each key must be a known class without a model of"
                " its own, each value an inferred beam-frame class"
            )
        return self

    @field_validator("frame_kinds")
    @classmethod
    def _known_frame_classes(
        cls, value: dict[str, FrameKind] | None
    ) -> dict[str, FrameKind] | None:
        if value is not None:
            known_class_names(tuple(value))
        return value

    def frame_kind(self, class_name: str) -> FrameKind:
        """The reference frame kind of a class ('object' unless listed; the default table's
        kinds while unresolved)."""
        kinds = DEFAULT_FRAME_KINDS if self.frame_kinds is None else self.frame_kinds
        return kinds.get(class_name, "object")

    def icp_params(self) -> IcpParams:
        """The registration bounds as `IcpParams`."""
        import numpy as np  # here, not at the top: planning reads this module

        from sonarmap.stages.kernels.object_frame import IcpParams

        return IcpParams(
            max_correspondence_m=self.icp_max_correspondence_m,
            max_iterations=self.icp_max_iterations,
            min_fitness=self.icp_min_fitness,
            max_rmse_m=self.icp_max_rmse_m,
            max_translation_m=self.icp_max_translation_m,
            max_rotation_rad=float(np.deg2rad(self.icp_max_rotation_deg)),
            voxel_m=self.reference_voxel_m,
        )
