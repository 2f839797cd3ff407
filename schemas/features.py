"""Column contract of `features.parquet`, the output of the `features` stage.

One row per CFAR detection (a polar image cell) of either sonar in one keyframe. Rows
are sorted by (keyframe_id, sonar with "horizontal" first, range_bin, beam), and
`feature_id` numbers them 0..n-1 within each keyframe in that order, so a feature is
named by (keyframe_id, feature_id) across both sonars.

`angle_rad` is the resolved beam angle of the cell: the bearing theta = atan2(y, x) of
the horizontal sonar, or the fan angle atan2(z, x) of the vertical sonar (its elevation
angle, measured in the unrolled frame at the vertical sonar's origin; positive up).
"""

from __future__ import annotations

import pyarrow as pa

__all__ = ["FEATURES_SCHEMA", "SONARS"]

SONARS: tuple[str, ...] = ("horizontal", "vertical")
"""Values of the `sonar` column, in row order."""

FEATURES_SCHEMA = pa.schema(
    [
        pa.field("keyframe_id", pa.int64(), nullable=False),
        pa.field("feature_id", pa.int64(), nullable=False),
        pa.field("sonar", pa.string(), nullable=False),
        pa.field("range_bin", pa.int64(), nullable=False),
        pa.field("beam", pa.int64(), nullable=False),
        pa.field("range_m", pa.float64(), nullable=False),
        pa.field("angle_rad", pa.float64(), nullable=False),
        pa.field("intensity", pa.float32(), nullable=False),
    ]
)
"""`features.parquet`: keyframe id, per-keyframe feature id, sonar, polar cell (range_bin =
image row, beam = image column), bin-centre range [m], beam angle [rad], image level."""
