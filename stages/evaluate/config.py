"""Config section `evaluate` (imports no numpy or pyarrow: planning reads it)."""

from __future__ import annotations

from collections.abc import Iterable

from pydantic import Field, field_validator

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable, known_class_names
from sonarmap.stages.base import StageConfig

__all__ = ["EvaluateConfig"]


class EvaluateConfig(StageConfig):
    """Config section `evaluate`."""

    tolerance_m: float = Field(
        0.1, gt=0.0, le=1000.0, description="precision/completeness distance"
    )
    completeness_classes: tuple[str, ...] | None = Field(
        None,
        description="classes whose surface completeness measures; null: the class table's"
        " classes marked `completeness` (by default the two piling classes)",
    )
    surface_samples_per_m2: float = Field(
        100.0, gt=0.0, le=1000000.0, description="completeness sampling density (10 cm spacing)"
    )
    seed: int = Field(0, ge=0, le=2**32 - 1, description="seed of the surface sampling")
    max_range_m: float | None = Field(
        None, gt=0.0, le=1000.0, description="visible surface's range; None: sensors' (else 30)"
    )
    fan_width_deg: float | None = Field(None, gt=0, le=360, description="None: sensors' fov_deg")
    aperture_deg: float | None = Field(
        None, gt=0.0, lt=180.0, description="horizontal sonar's; None: sensors' (else 20)"
    )
    side_view_pilings: int = Field(3, ge=1, le=8, description="pilings in side_view.png")
    trust_cell_m: float = Field(1.0, gt=0.0, le=100.0, description="trust: world column side")
    trust_height_tolerance_m: float = Field(
        0.6, gt=0.0, le=100.0, description="trust: a fused point this close in height agrees"
    )

    @field_validator("completeness_classes")
    @classmethod
    def _sane_classes(cls, value: tuple[str, ...] | None) -> tuple[str, ...] | None:
        return None if value is None else known_class_names(value)

    def class_names_used(self) -> dict[str, Iterable[str]]:
        """Class names by field (checked against the class table when the config loads)."""
        return {"completeness_classes": self.completeness_classes or ()}

    def completeness(self, table: ClassTable = DEFAULT_TABLE) -> tuple[str, ...]:
        """The classes completeness measures: as given, or the table's marked ones (a
        flag that did nothing while this field defaulted to the default table's)."""
        if self.completeness_classes is None:
            return table.completeness
        return self.completeness_classes
