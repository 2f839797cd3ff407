"""Annotation files: object classes drawn by hand on field recordings' horizontal sonar.

Simulated recordings carry label images; field recordings do not, so a researcher
draws boxes or polygons on the keyframes they want to train on. One YAML (or JSON)
file per recording, `<recording stem>.annotations.yaml` beside it:

    format: sonarmap-annotations/1
    keyframes:
      - t_ns: 1700000000123456789          # the horizontal ping's time (keyframes.parquet t_ns)
        objects:
          - {class_name: cylindrical_piling, box_m: {x_min_m: 5.4, x_max_m: 6.3, y_min_m: 2.5, y_max_m: 3.4}}
          - {class_name: seawall, polygon_m: [[8.0, -4.0], [9.5, 2.0], [9.0, 2.2], [7.6, -3.9]]}

Keyframes are named by time, not keyframe id: ids number the keyframes the current
`keyframes` config selects, so they shift whenever the keyframe spacing changes,
while a ping's time is fixed by the recording. Shapes are in the horizontal sonar's
frame projected onto its fan plane (REP 103, x forward, y left, metres), the frame of
objects.parquet and of the Cartesian overlay sonarmap draws (forward up, right to the
right: x is the vertical axis, y is minus the horizontal axis).

Every object of a listed keyframe should be drawn: cells outside all shapes get class
"none", as in a simulator label image. Keyframes that are not listed are not used.
"""

from __future__ import annotations

import math
from typing import Final, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationInfo,
    field_validator,
    model_validator,
)

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable

__all__ = [
    "ANNOTATION_FORMAT",
    "AnnotatedKeyframe",
    "AnnotatedObject",
    "AnnotationFile",
    "Box",
]

ANNOTATION_FORMAT: Final = "sonarmap-annotations/1"
"""The `format` line of an annotation file (bumped if its meaning ever changes)."""


class _Model(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class Box(_Model):
    """Axis-aligned box in the horizontal sonar frame [m]."""

    x_min_m: float = Field(allow_inf_nan=False)
    x_max_m: float = Field(allow_inf_nan=False)
    y_min_m: float = Field(allow_inf_nan=False)
    y_max_m: float = Field(allow_inf_nan=False)

    @model_validator(mode="after")
    def _ordered(self) -> Box:
        if not (self.x_min_m < self.x_max_m and self.y_min_m < self.y_max_m):
            raise ValueError("box needs x_min_m < x_max_m and y_min_m < y_max_m")
        return self


class AnnotatedObject(_Model):
    """One object: a class of the class table and exactly one shape (validate with
    `context={"classes": table}` for a table other than the default)."""

    class_name: str
    box_m: Box | None = None
    polygon_m: tuple[tuple[float, float], ...] | None = Field(
        None, description="vertices (x, y) [m], in order, at least 3; closed implicitly"
    )

    @field_validator("class_name")
    @classmethod
    def _known_class(cls, name: str, info: ValidationInfo) -> str:
        table = (info.context or {}).get("classes", DEFAULT_TABLE)
        assert isinstance(table, ClassTable)
        table.check([name], "", unknown_ok=False)
        return name

    @field_validator("polygon_m")
    @classmethod
    def _valid_polygon(
        cls, poly: tuple[tuple[float, float], ...] | None
    ) -> tuple[tuple[float, float], ...] | None:
        if poly is None:
            return None
        if len(poly) < 3:
            raise ValueError(f"polygon needs at least 3 vertices, got {len(poly)}")
        if not all(math.isfinite(v) for p in poly for v in p):
            raise ValueError("polygon vertices must be finite numbers")
        # Shoelace area: a degenerate polygon (collinear or repeated vertices) covers no cell.
        area = 0.5 * abs(
            sum(
                x0 * y1 - x1 * y0
                for (x0, y0), (x1, y1) in zip(poly, poly[1:] + poly[:1], strict=True)
            )
        )
        if area <= 0.0:
            raise ValueError("polygon has zero area")
        return poly

    @model_validator(mode="after")
    def _one_shape(self) -> AnnotatedObject:
        if (self.box_m is None) == (self.polygon_m is None):
            raise ValueError("give exactly one of box_m or polygon_m")
        return self

    def vertices_m(self) -> tuple[tuple[float, float], ...]:
        """The shape as polygon vertices (x, y) [m] (a box's four corners)."""
        if self.polygon_m is not None:
            return self.polygon_m
        b = self.box_m
        assert b is not None
        return (
            (b.x_min_m, b.y_min_m),
            (b.x_max_m, b.y_min_m),
            (b.x_max_m, b.y_max_m),
            (b.x_min_m, b.y_max_m),
        )


class AnnotatedKeyframe(_Model):
    """The objects drawn on one horizontal ping (where shapes overlap, the later wins)."""

    # A keyframe time is an int64 (keyframes.parquet t_ns): larger values cannot match one.
    t_ns: int = Field(
        ge=0, le=2**63 - 1, description="horizontal ping time [ns] (keyframes.parquet t_ns)"
    )
    objects: tuple[AnnotatedObject, ...] = ()


class AnnotationFile(_Model):
    """A recording's annotation file (see the module docstring for the format)."""

    format: Literal["sonarmap-annotations/1"] = ANNOTATION_FORMAT
    time_tolerance_ms: float = Field(
        1.0,
        gt=0,
        allow_inf_nan=False,
        description="an entry labels the keyframe within this time [ms]; keep it under "
        "half the ping period so a neighbouring ping never matches",
    )
    keyframes: tuple[AnnotatedKeyframe, ...] = Field(min_length=1)

    @model_validator(mode="after")
    def _unique_times(self) -> AnnotationFile:
        times = [k.t_ns for k in self.keyframes]
        if len(set(times)) != len(times):
            dup = next(t for t in times if times.count(t) > 1)
            raise ValueError(f"t_ns {dup} is listed twice")
        return self
