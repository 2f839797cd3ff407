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

from sonarmap.stages.kernels.voxels import column_ids

__all__ = ["contradicted_by_fused"]


_QUERY_CHUNK = 1 << 19
"""Inferred points judged per pass: the temporaries stay near 100 MB on a dense map of
millions of points, whose own arrays already set the stage's peak memory."""


def contradicted_by_fused(
    inferred_xyz_m: np.ndarray,
    fused_xyz_m: np.ndarray,
    *,
    cell_m: float,
    height_tolerance_m: float,
    min_fused: int,
    rows: np.ndarray | None = None,
) -> np.ndarray:
    """Which inferred points no fused point of their column supports.

    Args:
        inferred_xyz_m: (n, 3) inferred points in the world frame [m].
        fused_xyz_m: (m, 3) fused points in the world frame [m].
        cell_m: side of a column's square cell [m].
        height_tolerance_m: a fused point within this height of an inferred point in its
            column supports it.
        min_fused: columns with fewer fused points decide nothing.
        rows: judge only these rows of `inferred_xyz_m` (None: all), without copying the
            others.

    Returns:
        (len(rows) or n,) bool: True where the column holds at least `min_fused` fused
        points and none lies within `height_tolerance_m` of the point's height.
    """
    q = np.asarray(inferred_xyz_m, np.float64).reshape(-1, 3)
    f = np.asarray(fused_xyz_m, np.float64).reshape(-1, 3)
    judged = np.arange(len(q)) if rows is None else np.asarray(rows, np.int64)
    out = np.zeros(len(judged), bool)
    if len(judged) == 0 or len(f) == 0:
        return out
    columns, f_rank = np.unique(column_ids(f[:, :2], cell_m), return_inverse=True)
    counts = np.bincount(f_rank, minlength=len(columns))
    starts = np.concatenate([[0], np.cumsum(counts)])
    # Fused heights sorted by (column, z); offsetting z by the column rank times more than
    # the height span keeps one sorted key for all columns, searched once per query.
    order = np.lexsort((f[:, 2], f_rank))
    f_z = f[order, 2]
    z0, span = float(f_z.min()), float(np.ptp(f_z)) + 1.0
    f_key = f_rank[order] * span + (f_z - z0)
    for a in range(0, len(judged), _QUERY_CHUNK):
        chunk = q[judged[a : a + _QUERY_CHUNK]]
        q_col = column_ids(chunk[:, :2], cell_m)
        pos = np.minimum(np.searchsorted(columns, q_col), len(columns) - 1)
        enough = (columns[pos] == q_col) & (counts[pos] >= min_fused)
        lo, last = starts[pos], starts[pos + 1] - 1
        at = np.clip(np.searchsorted(f_key, pos * span + (chunk[:, 2] - z0)), lo, last)
        below = np.maximum(at - 1, lo)
        nearest = np.minimum(np.abs(f_z[at] - chunk[:, 2]), np.abs(f_z[below] - chunk[:, 2]))
        out[a : a + len(chunk)] = enough & (nearest > height_tolerance_m)
    return out
