"""Config section `voxelize` (imports no numpy or pyarrow: planning reads it)."""

from __future__ import annotations

from collections.abc import Iterable

from pydantic import Field, field_validator

from sonarmap.schemas.classes import known_class_names
from sonarmap.stages.base import StageConfig
from sonarmap.stages.kernels.choices import DEFAULT_FRAME_KINDS

__all__ = ["DEFAULT_EVIDENCE_CLASSES", "XYZ", "VoxelizeConfig"]

XYZ = ("x_m", "y_m", "z_m")
"""The point columns the stage reads of each point table."""

DEFAULT_EVIDENCE_CLASSES: tuple[str, ...] = tuple(
    sorted(c for c, kind in DEFAULT_FRAME_KINDS.items() if kind == "beam")
)
"""The beam-frame classes: their frames need no registration, so nothing upstream checks
that an object fits its class's model (a piling's ICP registration does). The check's
three numbers (1 m cells, 0.6 m, 5 points) come from one rule, measured in
docs/decisions/008-fused-evidence-check.md."""


class VoxelizeConfig(StageConfig):
    """Config section `voxelize`."""

    voxel_size_m: float = Field(
        0.1, ge=0.001, le=100.0, description="edge of a map voxel (paper: 10 cm)"
    )
    drop_above_surface: bool = Field(True, description="drop world points with z > 0")
    evidence_classes: tuple[str, ...] = Field(
        DEFAULT_EVIDENCE_CLASSES,
        description="classes whose inferred points the fused points of their world column"
        " may contradict and so drop (empty: keep every inferred point, as the paper)",
    )
    evidence_cell_m: float = Field(
        1.0, gt=0.0, le=100.0, description="side of a world column's square cell"
    )
    evidence_height_tolerance_m: float = Field(
        0.6, ge=0.0, le=100.0, description="a fused point this close in height supports"
    )
    evidence_min_fused: int = Field(
        5, ge=1, le=1_000_000, description="columns with fewer fused points decide nothing"
    )

    @field_validator("evidence_classes")
    @classmethod
    def _known_classes(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        # A set: one order (sorted, each once), so a reordered list keys the same artifact.
        return tuple(sorted(set(known_class_names(value))))

    def class_names_used(self) -> dict[str, Iterable[str]]:
        """Class names by field (checked against the class table when the config loads)."""
        return {"evidence_classes": self.evidence_classes}
