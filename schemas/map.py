"""Column contracts of the map artifacts: `map.parquet`, `voxels.parquet` (stage
`voxelize`) and `errors.parquet` (stage `evaluate`).

Map points are in the world frame (the SLAM / odometry frame, REP 103: x forward,
y left, z up, z = 0 at the water surface). The standard map (the paper's benchmark)
is the rows with `source == "fused"`; the semantic map (the proposed method) is all
rows. Voxel indices are floor(coordinate / voxel_size_m).
"""

from __future__ import annotations

import pyarrow as pa

__all__ = [
    "ERRORS_SCHEMA",
    "MAP_NAMES",
    "MAP_SCHEMA",
    "MAP_SORT_KEYS",
    "NO_CLASS",
    "VOXELS_SCHEMA",
]

MAP_NAMES: tuple[str, ...] = ("standard", "semantic")
"""Values of the `map` column: standard = fused points only, semantic = fused + inferred."""

NO_CLASS = "none"
"""`class_name` of a fused point that belongs to no classified object."""

MAP_SORT_KEYS: tuple[str, ...] = (
    "keyframe_id",
    "frame_id",
    "source",
    "class_name",
    "x_m",
    "y_m",
    "z_m",
)
"""Row order of `map.parquet` and `errors.parquet`."""

MAP_SCHEMA = pa.schema(
    [
        pa.field("keyframe_id", pa.int64(), nullable=False),
        pa.field("frame_id", pa.int64(), nullable=False),
        pa.field("x_m", pa.float64(), nullable=False),
        pa.field("y_m", pa.float64(), nullable=False),
        pa.field("z_m", pa.float64(), nullable=False),
        pa.field("source", pa.string(), nullable=False),
        pa.field("class_name", pa.string(), nullable=False),
    ]
)
"""map.parquet: keyframe the point was observed in (or whose submap it belongs to),
its submap frame (`submap_frames.parquet` frame_id; -1: the keyframe itself, see
`sonarmap.schemas.submaps.KEYFRAME_FRAME_ID`), world position [m], source
(`fused` | `inferred`), class of its object (`none` when unclassified, `unknown` when
the classifier was not confident). Sorted by MAP_SORT_KEYS."""

VOXELS_SCHEMA = pa.schema(
    [
        pa.field("map", pa.string(), nullable=False),
        pa.field("ix", pa.int64(), nullable=False),
        pa.field("iy", pa.int64(), nullable=False),
        pa.field("iz", pa.int64(), nullable=False),
        pa.field("n_points", pa.int64(), nullable=False),
    ]
)
"""voxels.parquet: one row per occupied voxel of each map (MAP_NAMES), integer voxel
index floor(x_m / voxel_size_m) etc., number of map points inside. Sorted by
(map, ix, iy, iz)."""

ERRORS_SCHEMA = pa.schema(
    [
        *MAP_SCHEMA,
        pa.field("error_m", pa.float64(), nullable=False),
    ]
)
"""errors.parquet: every map.parquet row (same order) with its absolute error [m], the
unsigned distance to the ground-truth mesh."""
