"""Column contracts of the data that the figure stages draw and no other stage reads.

- `plot_points.parquet` (stage `slam`): the horizontal sonar's features registered with the
  estimated poses in the world frame, thinned to `slam.plot_max_points` for drawing.
- `side_view.parquet` (stage `evaluate`): the points of the side views of the pilings with
  the most map points near them, one row per point, in panel order: `h_m` along the panel's
  horizontal axis (`axis_label`, relative to the piling's centre), `z_m` the height.
"""

from __future__ import annotations

import pyarrow as pa

__all__ = ["PLOT_POINTS_SCHEMA", "SIDE_VIEW_KINDS", "SIDE_VIEW_SCHEMA"]

PLOT_POINTS_SCHEMA = pa.schema([pa.field("x_m", pa.float64()), pa.field("y_m", pa.float64())])

SIDE_VIEW_KINDS: tuple[str, ...] = ("fused", "inferred", "truth")
"""Values of `kind`: fused and inferred map points, samples of the true surface."""

SIDE_VIEW_SCHEMA = pa.schema(
    [
        pa.field("panel", pa.int32()),
        pa.field("title", pa.string()),
        pa.field("axis_label", pa.string()),
        pa.field("kind", pa.string()),
        pa.field("h_m", pa.float64()),
        pa.field("z_m", pa.float64()),
    ]
)
