"""Multi-view class pooling: one object, many sightings, one class (our addition to Sec. IV.C).

The paper classifies every keyframe's objects on their own. A piling is seen from many
keyframes, though, close up in some and at 25 m in others, where a 1 deg beam is as wide as
the piling and a round one looks like a square one. Here each sighting's class
distribution (the Monte-Carlo mean of `sonarmap.stages.classify.cnn.mc_predict`) is pooled with those of the
sightings of the same place in nearby keyframes, by a weighted log-linear opinion pool

    p(c) ∝ exp( sum_j w_j log p_j(c) / sum_j w_j ),

which is the normalised weighted geometric mean of the distributions (Genest & Zidek,
Statistical Science 1(1), 1986). Unlike the arithmetic mean it lets agreeing confident
views stay confident, and one confidently wrong view cannot outvote several right ones;
unlike a product (naive Bayes) it does not grow more certain with the number of
correlated views. A sighting's weight falls with range, w = 1 / (1 + (r / r_s)^4): beyond
r_s the patch hardly resolves the shape.

Sightings are the same place when their centroids, mapped into the world with the
dead-reckoning poses, lie within a radius, and the vehicle travelled at most a window
between them (dead reckoning drifts with distance, so only nearby keyframes are compared;
the association is a neighbourhood per sighting, not a transitive track, so two
neighbouring pilings never chain into one).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["along_track_m", "fan_coverage", "pool_views", "sighting_world_xy"]

_LOG_FLOOR = 1e-6
"""Probabilities are clipped here before the log: a single 0 would veto a class outright."""


def along_track_m(poses_xy_m: np.ndarray) -> np.ndarray:
    """Distance travelled up to each keyframe [m] (cumulative planar path length).

    Args:
        poses_xy_m: (k, 2) keyframe positions in keyframe order.
    """
    steps = np.hypot(*np.diff(np.asarray(poses_xy_m, np.float64), axis=0).T)
    return np.concatenate([[0.0], np.cumsum(steps)])


def sighting_world_xy(
    centroid_xy_m: np.ndarray, pose_xy_yaw: np.ndarray, T_base_sonar: np.ndarray
) -> np.ndarray:
    """Planar world position of each sighting's centroid.

    Args:
        centroid_xy_m: (n, 2) centroid in the horizontal sonar's fan plane [m].
        pose_xy_yaw: (n, 3) the vehicle pose (x [m], y [m], yaw [rad]) of each sighting's
            keyframe.
        T_base_sonar: (4, 4) mounting of the horizontal sonar on the vehicle.

    Returns:
        (n, 2) world x, y [m] (roll and pitch ignored: the pooling radius absorbs them).
    """
    T = np.asarray(T_base_sonar, np.float64)
    base = np.asarray(centroid_xy_m, np.float64) @ T[:2, :2].T + T[:2, 3]
    c, s = np.cos(pose_xy_yaw[:, 2]), np.sin(pose_xy_yaw[:, 2])
    return np.column_stack(
        [
            pose_xy_yaw[:, 0] + c * base[:, 0] - s * base[:, 1],
            pose_xy_yaw[:, 1] + s * base[:, 0] + c * base[:, 1],
        ]
    )


def pool_views(
    probabilities: np.ndarray,
    world_xy_m: np.ndarray,
    keyframe_id: np.ndarray,
    along_track: np.ndarray,
    range_m: np.ndarray,
    *,
    radius_m: float,
    window_m: float,
    range_scale_m: float | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Log-linear pool of each sighting's class distribution with its neighbours'.

    Args:
        probabilities: (n, c) class distribution of each sighting (rows sum to 1).
        world_xy_m: (n, 2) sighting positions in the world (dead reckoning).
        keyframe_id: (n,) keyframe of each sighting; sightings in one keyframe are
            different objects and never pooled.
        along_track: (n,) distance travelled at each sighting's keyframe [m].
        range_m: (n,) range of each sighting from the sonar [m].
        radius_m: sightings closer than this in the world are the same object.
        window_m: ... and only when at most this far apart along the track.
        range_scale_m: r_s of the range weight; None: equal weights.

    Returns:
        pooled (n, c) distributions and n_views (n,) (1: the sighting alone).
    """
    prob = np.asarray(probabilities, np.float64)
    n = len(prob)
    if n == 0:
        return prob.copy(), np.zeros(0, np.int64)
    pairs = cKDTree(world_xy_m).query_pairs(radius_m, output_type="ndarray")
    a, b = pairs[:, 0], pairs[:, 1]
    same = (keyframe_id[a] != keyframe_id[b]) & (
        np.abs(along_track[a] - along_track[b]) <= window_m
    )
    a, b = a[same], b[same]
    self_ = np.arange(n)
    dst, src = np.concatenate([self_, a, b]), np.concatenate([self_, b, a])
    r = np.asarray(range_m, np.float64)
    weight = np.ones(n) if range_scale_m is None else 1.0 / (1.0 + (r / range_scale_m) ** 4)
    log_p = np.log(np.clip(prob, _LOG_FLOOR, 1.0))
    # Sorting by destination first makes the float sums independent of the k-d tree's
    # pair order, so the output is byte-identical run to run.
    order = np.lexsort((src, dst))
    dst, src = dst[order], src[order]
    num = np.zeros_like(log_p)
    np.add.at(num, dst, weight[src, None] * log_p[src])
    den = np.bincount(dst, weights=weight[src], minlength=n)
    pooled_log = num / den[:, None]
    pooled_log -= pooled_log.max(axis=1, keepdims=True)
    pooled = np.exp(pooled_log)
    pooled /= pooled.sum(axis=1, keepdims=True)
    return pooled, np.bincount(dst, minlength=n).astype(np.int64)


def fan_coverage(
    world_xy_m: np.ndarray,
    along_track: np.ndarray,
    sonar_xy_yaw: np.ndarray,
    fans: np.ndarray,
    keyframe_along: np.ndarray,
    window_m: float,
    margin_m: float = 0.0,
) -> np.ndarray:
    """How many keyframes' horizontal fans cover each place: the place lies at least
    `margin_m` inside the keyframe's range and bearing interval (the pooling radius: the
    whole of what counts as that place is in view), and the keyframe at most `window_m` of
    travel from the place's own (the pooling's window). Occlusion is not modelled.

    Args:
        world_xy_m: (n, 2) places in the world (dead reckoning).
        along_track: (n,) distance travelled at each place's own keyframe [m].
        sonar_xy_yaw: (k, 3) the horizontal sonar's world pose at each keyframe.
        fans: (k, 4) each keyframe's image: nearest and farthest range [m], smallest and
            largest bearing [rad] (bearing = atan2(y, x) in the fan plane).
        keyframe_along: (k,) distance travelled at each keyframe [m].
        window_m: the pooling window.
        margin_m: how far inside the fan's edges a place must be to count as covered.

    Returns:
        (n,) int64 count of keyframes covering each place.
    """
    places = np.asarray(world_xy_m, np.float64)
    cover = np.zeros(len(places), np.int64)
    # One keyframe at a time, vectorised over the places: memory stays O(n).
    for (x, y, yaw), (r0, r1, a0, a1), at in zip(sonar_xy_yaw, fans, keyframe_along, strict=True):
        near = np.abs(np.asarray(along_track) - at) <= window_m
        dx, dy = places[:, 0] - x, places[:, 1] - y
        r = np.hypot(dx, dy)
        bearing = np.angle(np.exp(1j * (np.arctan2(dy, dx) - yaw)))
        inside = np.minimum(bearing - a0, a1 - bearing)  # to the nearer side edge [rad]
        to_side = r * np.sin(np.clip(inside, 0.0, np.pi / 2))
        in_range = (r - r0 >= margin_m) & (r1 - r >= margin_m)
        cover += near & in_range & (inside >= 0) & (to_side >= margin_m)
    return cover
