"""Column contract of `keyframes.parquet` (docs/architecture.md#contracts), one row per keyframe.

t_ns is the horizontal ping's time; the dead-reckoning pose is interpolated at t_ns
(SE(2) + depth, never extrapolated); ground-truth columns are null without truth.
"""

from __future__ import annotations

import pyarrow as pa

__all__ = ["GT_POSE_COLUMNS", "KEYFRAMES_SCHEMA", "KEYFRAME_REASONS", "POSE_COLUMNS"]

POSE_COLUMNS: tuple[str, ...] = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
GT_POSE_COLUMNS: tuple[str, ...] = tuple(f"gt_{c}" for c in POSE_COLUMNS)

KEYFRAME_REASONS: tuple[str, ...] = ("first", "translation", "rotation")
"""Why a ping pair became a keyframe: the first posed pair, moved spacing_m, turned rotation_deg."""

KEYFRAMES_SCHEMA = pa.schema(
    [
        pa.field("keyframe_id", pa.int64(), nullable=False),
        pa.field("t_ns", pa.int64(), nullable=False),
        pa.field("t_vertical_ns", pa.int64(), nullable=False),
        pa.field("ping_index_horizontal", pa.int64(), nullable=False),
        pa.field("ping_index_vertical", pa.int64(), nullable=False),
        *[pa.field(c, pa.float64(), nullable=False) for c in POSE_COLUMNS],
        *[pa.field(c, pa.float64(), nullable=True) for c in GT_POSE_COLUMNS],
        pa.field("reason", pa.string(), nullable=False),
    ]
)
"""keyframes.parquet: keyframe_id (0..n-1, sorted), t_ns [ns] (horizontal ping),
t_vertical_ns [ns] (paired vertical ping), ping indices into each sonar's stream,
dead-reckoning pose [m, rad], ground-truth pose (null when absent), reason."""
