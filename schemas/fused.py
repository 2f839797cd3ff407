"""Column contract of `fused.parquet`, the output of the `fuse` stage.

One row per accepted association of a horizontal and a vertical feature of one keyframe
(paper Sec. IV.B). Coordinates are in the horizontal sonar frame (`sonar_horizontal`,
REP 103: x forward, y left, z up) and satisfy paper Eq. 1 exactly:
x = R cos(phi) cos(theta), y = R cos(phi) sin(theta), z = R sin(phi) with R = range_m,
theta = bearing_rad, phi = elevation_rad. Rows are sorted by (keyframe_id,
feature_id_horizontal). No value is ever NaN.
"""

from __future__ import annotations

import pyarrow as pa

__all__ = ["FUSED_SCHEMA"]

FUSED_SCHEMA = pa.schema(
    [
        pa.field("keyframe_id", pa.int64(), nullable=False),
        pa.field("feature_id_horizontal", pa.int64(), nullable=False),
        pa.field("feature_id_vertical", pa.int64(), nullable=False),
        pa.field("range_m", pa.float64(), nullable=False),
        pa.field("bearing_rad", pa.float64(), nullable=False),
        pa.field("elevation_rad", pa.float64(), nullable=False),
        pa.field("x_m", pa.float64(), nullable=False),
        pa.field("y_m", pa.float64(), nullable=False),
        pa.field("z_m", pa.float64(), nullable=False),
        pa.field("cost", pa.float64(), nullable=False),
        pa.field("confidence", pa.float64(), nullable=False),
    ]
)
"""`fused.parquet`: keyframe id, the two feature ids (`features.parquet` feature_id of the
horizontal and the vertical detection), Eq. 3 range [m], bearing and elevation [rad],
the point in the horizontal sonar frame [m], patch cost (Eq. 5, normalised intensity
units) and confidence (Eq. 6, dimensionless, at most 1)."""
