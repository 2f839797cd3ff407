"""Scan-matching inputs thinned and outlier-filtered before ICP.

The authors' SLAM front end (SSLAM `feature.yaml`, docs/authors-code.md section 2.2) turns each keyframe's features into metres, thins
them on a 0.5 m grid (libpointmatcher OctreeGrid) and then removes the points with fewer
than 5 neighbours within 1.0 m (PCL RadiusOutlierRemoval). The order matters for cost:
after thinning, a 1 m disc holds at most about (2 r / voxel + 1)^2 points whatever the
number of detections, so the neighbour count is linear in the thinned points, and those
are bounded by the area the sonar sees over the voxel area. A false detection rarely has
five others within a metre once its neighbours are merged into voxels; a surface does.
A keyframe still holding more than a budget (a dense flood passes the filter) keeps the
points with the most neighbours: a surface returns from the same place beam after beam,
so its points are denser than the speckle around it.

Everything here is vectorised over all keyframes at once: the keyframes are stacked
apart along a third axis, far enough that no neighbourhood spans two of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sonarmap.stages.kernels.lazy import lazy

spatial = lazy("scipy.spatial")

__all__ = [
    "RANK_RADIUS_M",
    "ThinnedPoints",
    "cell_inliers",
    "densest",
    "neighbour_counts",
    "radius_inliers",
    "thin_and_filter",
    "voxel_thin",
]

RANK_RADIUS_M = 1.0
"""Neighbourhood radius that ranks points for the budget when the outlier filter is off."""


def voxel_thin(keyframe: np.ndarray, points: np.ndarray, voxel_m: float) -> tuple[np.ndarray, ...]:
    """Centroids of the occupied (keyframe, voxel) cells, sorted by keyframe then voxel.

    Per keyframe this is `sonarmap.stages.slam.scan_matching.voxel_downsample` (same
    order, same sums in input order), done for every keyframe in one pass.

    Args:
        keyframe: (N,) int keyframe index of each point (any order).
        points: (N, 2) points [m].
        voxel_m: voxel size [m].

    Returns:
        (keyframe (M,), centroids (M, 2)).
    """
    if len(points) == 0:
        return np.zeros(0, np.int64), np.zeros((0, 2))
    cells = np.floor(points / voxel_m).astype(np.int64)
    low = cells.min(axis=0)
    span = cells.max(axis=0) - low + 1
    k = np.asarray(keyframe, np.int64)
    k_low, k_span = int(k.min()), int(k.max() - k.min() + 1)
    if float(span[0]) * float(span[1]) * k_span < 2**62:
        key = ((k - k_low) * span[0] + (cells[:, 0] - low[0])) * span[1] + (cells[:, 1] - low[1])
        uniq, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
        kf = uniq // (span[0] * span[1]) + k_low
    else:  # absurd extents: the row-wise unique, slower, no overflow
        rows = np.column_stack([k, cells])
        uniq, inverse, counts = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
        kf = uniq[:, 0]
    inverse = inverse.reshape(-1)
    sums = np.stack(
        [np.bincount(inverse, points[:, i], minlength=len(counts)) for i in range(2)], axis=1
    )
    return kf.astype(np.int64), sums / counts[:, None]


def neighbour_counts(keyframe: np.ndarray, points: np.ndarray, radius_m: float) -> np.ndarray:
    """(N,) int: other points of the same keyframe within `radius_m` of each point.

    Args:
        keyframe: (N,) int keyframe index of each point.
        points: (N, 2) points [m].
        radius_m: neighbourhood radius [m].
    """
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    # Keyframes stacked 4 radii apart along z: a ball never reaches the next keyframe.
    z = (np.asarray(keyframe, np.float64) - float(np.min(keyframe))) * (4.0 * radius_m)
    lifted = np.column_stack([points, z])
    tree = spatial.cKDTree(lifted)
    return np.asarray(tree.query_ball_point(lifted, radius_m, return_length=True)) - 1


def radius_inliers(
    keyframe: np.ndarray, points: np.ndarray, radius_m: float, min_neighbours: int
) -> np.ndarray:
    """(N,) bool: points with at least `min_neighbours` other points of their own keyframe
    within `radius_m` (PCL's RadiusOutlierRemoval, per keyframe)."""
    return neighbour_counts(keyframe, points, radius_m) >= min_neighbours


def cell_inliers(
    keyframe: np.ndarray,
    beam: np.ndarray,
    range_bin: np.ndarray,
    detected: tuple[np.ndarray, np.ndarray, np.ndarray],
    half_beams: int,
    half_bins: int,
    min_neighbours: int,
) -> np.ndarray:
    """(N,) bool: cells with at least `min_neighbours` other detections of their keyframe
    within +-`half_beams` beams and +-`half_bins` range bins.

    Counted in the sonar's own cells, not in metres: the CFAR fixes a false-alarm rate per
    cell, so a false alarm's expected neighbours in this window are the same at every range
    (window cells x rate: 64 x 1e-3 = 0.06 at the defaults, and three or more in 4e-5 of
    them). A metric radius holds about r times more cells near the sonar than at range r:
    near-range false alarms pass it and a lone far piling's few returns do not.

    Args:
        keyframe, beam, range_bin: (N,) int cells to test.
        detected: (keyframe, beam, range_bin) of every detection to count (the cells tested
            among them: each is not its own neighbour).
        half_beams, half_bins: window half-widths [cells].
        min_neighbours: detections needed besides the cell itself.
    """
    if len(keyframe) == 0:
        return np.zeros(0, dtype=bool)
    dk, db, dr = (np.asarray(a, np.int64) for a in detected)
    k, b, r = (np.asarray(a, np.int64) for a in (keyframe, beam, range_bin))
    # One sorted key per detection (keyframe, beam, bin), padded by the window on both
    # axes so that no window wraps into the next beam or keyframe; a window's count is
    # then, per beam offset, one range of the sorted keys (two binary searches).
    lo_b, lo_r = min(db.min(), b.min()), min(dr.min(), r.min())
    span_r = max(dr.max(), r.max()) - lo_r + 1 + 2 * half_bins
    span_b = max(db.max(), b.max()) - lo_b + 1 + 2 * half_beams
    lo_k = min(dk.min(), k.min())

    def key(kf: np.ndarray, bm: np.ndarray, rb: np.ndarray) -> np.ndarray:
        return ((kf - lo_k) * span_b + (bm - lo_b + half_beams)) * span_r + (rb - lo_r + half_bins)

    keys = np.sort(key(dk, db, dr))
    found = np.zeros(len(k), dtype=np.int64)
    for offset in range(-half_beams, half_beams + 1):
        first = np.searchsorted(keys, key(k, b + offset, r - half_bins), side="left")
        last = np.searchsorted(keys, key(k, b + offset, r + half_bins), side="right")
        found += last - first
    return found - 1 >= min_neighbours


def densest(keyframe: np.ndarray, count: np.ndarray, max_points: int) -> np.ndarray:
    """(N,) bool: per keyframe, its `max_points` points with the most neighbours (ties: the
    earlier point); every point of a keyframe holding no more.

    Args:
        keyframe: (N,) ascending keyframe index of each point.
        count: (N,) neighbour count of each point (`neighbour_counts`).
        max_points: most points a keyframe keeps.
    """
    n = len(keyframe)
    order = np.lexsort((np.arange(n), -np.asarray(count), keyframe))
    ranked = keyframe[order]
    first = np.searchsorted(ranked, ranked, side="left")
    keep = np.zeros(n, dtype=bool)
    keep[order] = (np.arange(n) - first) < max_points
    return keep


@dataclass(frozen=True)
class ThinnedPoints:
    """Result of `thin_and_filter`: the kept points and what was dropped, in counts.

    Attributes:
        keyframe: (M,) keyframe index of each kept point (ascending).
        points: (M, 2) kept points [m].
        input_points: points given.
        thinned_points: voxels occupied (points after thinning).
        outliers: thinned points removed by the radius filter.
        over_budget_keyframes: keyframes held to the budget (`densest`).
        over_budget_points: points those lost.
    """

    keyframe: np.ndarray
    points: np.ndarray
    input_points: int
    thinned_points: int
    outliers: int
    over_budget_keyframes: int = 0
    over_budget_points: int = 0


def thin_and_filter(
    keyframe: np.ndarray,
    points: np.ndarray,
    voxel_m: float,
    radius_m: float | None,
    min_neighbours: int,
    max_points: int | None = None,
) -> ThinnedPoints:
    """Per keyframe: voxel centroids (`voxel_thin`), then the radius outlier filter
    (`radius_inliers`; `radius_m` None: off), then the point budget: a keyframe holding
    more than `max_points` keeps its densest (`densest`: neighbours within `radius_m`, or
    `RANK_RADIUS_M` with the filter off; None: no budget). Points stay in voxel order."""
    kf, thinned = voxel_thin(keyframe, points, voxel_m)
    if radius_m is None and max_points is None:
        return ThinnedPoints(kf, thinned, len(points), len(kf), 0)
    count = neighbour_counts(kf, thinned, RANK_RADIUS_M if radius_m is None else radius_m)
    keep = np.ones(len(kf), dtype=bool) if radius_m is None else count >= min_neighbours
    outliers = int((~keep).sum())
    over = lost = 0
    if max_points is not None and keep.any():
        held = np.unique(kf[keep], return_counts=True)[1]
        over = int((held > max_points).sum())
        budget = np.zeros(len(kf), dtype=bool)
        budget[keep] = densest(kf[keep], count[keep], max_points)
        lost = int(keep.sum() - budget.sum())
        keep = budget
    return ThinnedPoints(kf[keep], thinned[keep], len(points), len(kf), outliers, over, lost)
