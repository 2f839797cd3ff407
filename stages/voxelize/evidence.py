"""The fused points as evidence against inferred heights (our addition to paper Sec. IV.D).

A class model predicts the height of a 2D-only return from what the class looks like
elsewhere. Where the orthogonal pair has itself measured the same place in 3D, from
other keyframes, the fused points say at which heights that column of water holds
structure. An inferred point far from every fused height of a column with enough fused
points there is contradicted by direct measurement, and is dropped from the semantic
map. A column without enough fused points decides nothing: the prediction stands.

This catches what a class model cannot know: an object given the wrong class. A truss
near the surface that the classifier calls seawall receives wall heights down to the
limit of the aperture, while every fused point in its columns lies near the surface.

Columns are square cells of the world's horizontal plane; an inferred point is compared
with the fused points of its own cell only (a point near a cell edge sees fewer fused
neighbours, so it is contradicted less readily, never more). Everything is in the world
frame of the SLAM poses, after Eq. 4.
"""

from __future__ import annotations

import numpy as np

__all__ = ["contradicted_by_fused"]


def _column_ids(xy_m: np.ndarray, cell_m: float) -> np.ndarray:
    ij = np.floor(np.asarray(xy_m, np.float64) / cell_m).astype(np.int64)
    # 2^31 cells a side (2e8 km at 0.1 m) cannot collide.
    return (ij[:, 0] << 32) + (ij[:, 1] & 0xFFFFFFFF)


def contradicted_by_fused(
    inferred_xyz_m: np.ndarray,
    fused_xyz_m: np.ndarray,
    *,
    cell_m: float,
    height_tolerance_m: float,
    min_fused: int,
) -> np.ndarray:
    """Which inferred points no fused point of their column supports.

    Args:
        inferred_xyz_m: (n, 3) inferred points in the world frame [m].
        fused_xyz_m: (m, 3) fused points in the world frame [m].
        cell_m: side of a column's square cell [m].
        height_tolerance_m: a fused point within this height of an inferred point in its
            column supports it.
        min_fused: columns with fewer fused points decide nothing.

    Returns:
        (n,) bool: True where the column holds at least `min_fused` fused points and none
        lies within `height_tolerance_m` of the point's height.
    """
    q = np.asarray(inferred_xyz_m, np.float64).reshape(-1, 3)
    f = np.asarray(fused_xyz_m, np.float64).reshape(-1, 3)
    if len(q) == 0 or len(f) == 0:
        return np.zeros(len(q), bool)
    f_col = _column_ids(f[:, :2], cell_m)
    q_col = _column_ids(q[:, :2], cell_m)
    columns, f_rank = np.unique(f_col, return_inverse=True)
    counts = np.bincount(f_rank, minlength=len(columns))
    pos = np.searchsorted(columns, q_col)
    pos_c = np.minimum(pos, len(columns) - 1)
    in_known = columns[pos_c] == q_col
    q_rank = np.where(in_known, pos_c, -1)
    enough = in_known & (counts[pos_c] >= min_fused)
    # Nearest fused height within the column: fused points sorted by (column, z), then
    # one binary search of (column, z) per query, checking both neighbours.
    order = np.lexsort((f[:, 2], f_rank))
    f_rank_s, f_z = f_rank[order], f[order, 2]
    starts = np.concatenate([[0], np.cumsum(counts)])
    lo = np.where(enough, starts[np.maximum(q_rank, 0)], 0)
    hi = np.where(enough, starts[np.maximum(q_rank, 0) + 1], 0)
    # Offsetting z by the column rank keeps one sorted key for all columns.
    span = float(np.ptp(f_z)) + float(np.ptp(q[:, 2])) + 2.0 * height_tolerance_m + 1.0
    f_key = f_rank_s * span + (f_z - f_z.min())
    q_key = np.maximum(q_rank, 0) * span + (q[:, 2] - f_z.min())
    at = np.clip(np.searchsorted(f_key, q_key), lo, np.maximum(hi - 1, lo))
    below = np.clip(at - 1, lo, np.maximum(hi - 1, lo))
    nearest = np.minimum(np.abs(f_z[at] - q[:, 2]), np.abs(f_z[below] - q[:, 2]))
    return enough & (nearest > height_tolerance_m)
