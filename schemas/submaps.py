"""Column contracts of the dense-submap artifacts (stage `submaps`): `submap_frames.parquet`
and `submap_points.parquet`.

A submap frame is a sonar ping pair recorded between two keyframes that is mapped
too (`keyframes.submap_stride`). It is anchored to the keyframe before it: its pose is
the keyframe's pose composed with the dead-reckoning motion since the keyframe,
T_world_frame = T_world_keyframe @ T_keyframe_frame (`rel_*` columns, base_link to
base_link), so when SLAM moves a keyframe its submap moves with it (McConnell et al.,
"Large-Scale Dense 3D Mapping Using Submaps Derived From Orthogonal Imaging Sonars",
arXiv 2412.03760).
"""

from __future__ import annotations

import pyarrow as pa

from sonarmap.schemas.keyframes import GT_POSE_COLUMNS, POSE_COLUMNS
from sonarmap.schemas.points import POINTS_SCHEMA

__all__ = [
    "KEYFRAME_FRAME_ID",
    "REL_POSE_COLUMNS",
    "SUBMAP_FRAMES_SCHEMA",
    "SUBMAP_POINTS_SCHEMA",
    "SUBMAP_POINTS_SORT_KEYS",
]

KEYFRAME_FRAME_ID = -1
"""`frame_id` of map rows observed in a keyframe itself (not a submap frame)."""

REL_POSE_COLUMNS: tuple[str, ...] = tuple(f"rel_{c}" for c in POSE_COLUMNS)
"""T_keyframe_frame: the frame's base_link in its keyframe's base_link, from dead
reckoning [m, rad], R = Rz(yaw) Ry(pitch) Rx(roll)."""

SUBMAP_FRAMES_SCHEMA = pa.schema(
    [
        pa.field("frame_id", pa.int64(), nullable=False),
        pa.field("keyframe_id", pa.int64(), nullable=False),
        pa.field("t_ns", pa.int64(), nullable=False),
        pa.field("t_vertical_ns", pa.int64(), nullable=False),
        pa.field("ping_index_horizontal", pa.int64(), nullable=False),
        pa.field("ping_index_vertical", pa.int64(), nullable=False),
        *[pa.field(c, pa.float64(), nullable=False) for c in REL_POSE_COLUMNS],
        *[pa.field(c, pa.float64(), nullable=False) for c in POSE_COLUMNS],
        *[pa.field(c, pa.float64(), nullable=True) for c in GT_POSE_COLUMNS],
    ]
)
"""submap_frames.parquet: frame_id (0..n-1 in time order), the keyframe that owns it,
times and ping indices as in keyframes.parquet, the relative dead-reckoning pose
(REL_POSE_COLUMNS), the absolute dead-reckoning pose and the ground-truth pose (null
without truth). Sorted by frame_id."""

SUBMAP_POINTS_SCHEMA = pa.schema([pa.field("frame_id", pa.int64(), nullable=False), *POINTS_SCHEMA])
"""submap_points.parquet: every fused point of a submap frame (`source="fused"`, with
the keyframe object it lies on, object_id -1 and class "none" when on none) and the
heights inferred for its 2D-only returns (`source="inferred"`), in the frame's own
horizontal sonar frame (paper Eq. 1), columns as in points.parquet."""

SUBMAP_POINTS_SORT_KEYS: tuple[str, ...] = (
    "frame_id",
    "object_id",
    "source",
    "range_m",
    "bearing_rad",
    "z_m",
)
