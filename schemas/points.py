"""Column contract of `points.parquet`, the output of the `infer` stage.

One row per 3D point of a classified object in one keyframe: either a point of the
orthogonal fusion (`source == "fused"`) or a height predicted for a 2D-only return
by the object-class model (`source == "inferred"`, paper Eq. 8-9). Coordinates are
in the horizontal sonar frame (`sonar_horizontal`, REP 103: x forward, y left, z up)
and follow paper Eq. 1: x = R cos(phi) cos(theta), y = R cos(phi) sin(theta),
z = R sin(phi). Rows are sorted by (keyframe_id, object_id, source, range_m,
bearing_rad, z_m).
"""

from __future__ import annotations

import pyarrow as pa

__all__ = ["POINTS_SCHEMA", "POINT_SOURCES"]

POINT_SOURCES: tuple[str, ...] = ("fused", "inferred")
"""Values of the `source` column."""

POINTS_SCHEMA = pa.schema(
    [
        pa.field("keyframe_id", pa.int64(), nullable=False),
        pa.field("object_id", pa.int64(), nullable=False),
        pa.field("class_name", pa.string(), nullable=False),
        pa.field("source", pa.string(), nullable=False),
        pa.field("range_m", pa.float64(), nullable=False),
        pa.field("bearing_rad", pa.float64(), nullable=False),
        pa.field("elevation_rad", pa.float64(), nullable=False),
        pa.field("x_m", pa.float64(), nullable=False),
        pa.field("y_m", pa.float64(), nullable=False),
        pa.field("z_m", pa.float64(), nullable=False),
        pa.field("confidence", pa.float64(), nullable=False),
    ]
)
"""`points.parquet`: confidence is the fusion confidence (paper Eq. 6) for fused rows
and the posterior probability of the predicted height (see `sonarmap.stages.kernels.height_model`)
for inferred rows."""
