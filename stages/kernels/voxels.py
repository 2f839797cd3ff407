"""The voxelised map's points and voxel keys, shared by stage `voxelize` (which builds
the map) and stage `evaluate` (which scores it)."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from sonarmap.schemas.map import MAP_NAMES

__all__ = ["column_ids", "map_xyz", "standard_rows", "voxel_keys"]

_XYZ = ("x_m", "y_m", "z_m")


def standard_rows(map_table: pa.Table) -> pa.Table:
    return map_table.filter(pc.equal(map_table.column("source"), "fused"))


def map_xyz(map_table: pa.Table, name: str) -> np.ndarray:
    """(n, 3) world points [m] of one map ("standard": fused rows, "semantic": all)."""
    if name not in MAP_NAMES:
        raise ValueError(f"unknown map {name!r}; expected one of {MAP_NAMES}")
    t = standard_rows(map_table) if name == "standard" else map_table
    return np.stack([t.column(c).to_numpy() for c in _XYZ], axis=1).reshape(-1, 3)


def voxel_keys(voxel_ijk: np.ndarray) -> np.ndarray:
    """(n,) int64 key of each (n, 3) voxel index, one key per distinct voxel, ordered as
    the rows (ix, iy, iz) sort: counting unique keys is several times cheaper than
    unique rows."""
    ijk = np.asarray(voxel_ijk, dtype=np.int64).reshape(-1, 3)
    if len(ijk) == 0:
        return np.zeros(0, dtype=np.int64)
    ijk = ijk - ijk.min(axis=0)
    span = ijk.max(axis=0) + 1
    if float(span[0]) * float(span[1]) * float(span[2]) >= 2.0**63:
        return np.unique(ijk, axis=0, return_inverse=True)[1].reshape(-1).astype(np.int64)
    return (ijk[:, 0] * span[1] + ijk[:, 1]) * span[2] + ijk[:, 2]


def column_ids(xy_m: np.ndarray, cell_m: float) -> np.ndarray:
    """(n,) int64 id of the square world column (cell side `cell_m` [m]) of each (x, y)."""
    ij = np.floor(np.asarray(xy_m, np.float64) / cell_m).astype(np.int64)
    # Unique for up to 2^31 cells a side (200,000 km at 0.1 m).
    return (ij[:, 0] << 32) + (ij[:, 1] & 0xFFFFFFFF)
