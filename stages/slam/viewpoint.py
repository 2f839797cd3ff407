"""From which directions two keyframes see the structure a loop closure registers.

A sonar return comes from the part of a surface that faces the sensor. A curved surface (a
hull, a piling) seen from another side returns from another part of itself, so ICP between
the two views pairs points that are not the same place and is biased by up to the
surface's radius (docs/slam.md, Known limits: `moorings`). Flat walls do not have that
bias, but their points far off to one side are seen from directions as different.
"""

from __future__ import annotations

import numpy as np

from sonarmap.stages.kernels.lazy import lazy
from sonarmap.stages.slam.pose_graph import wrap_angle
from sonarmap.stages.slam.scan_matching import transform_points

spatial = lazy("scipy.spatial")

__all__ = ["covisible_points", "view_angles_deg", "view_change_deg"]


def view_angles_deg(points: np.ndarray, origin_a: np.ndarray, origin_b: np.ndarray) -> np.ndarray:
    """(N,) angle [deg] between the directions from which `origin_a` and `origin_b` see
    each of the (N, 2) points (all three in one frame)."""
    from_a = np.arctan2(points[:, 1] - origin_a[1], points[:, 0] - origin_a[0])
    from_b = np.arctan2(points[:, 1] - origin_b[1], points[:, 0] - origin_b[0])
    return np.degrees(np.abs(wrap_angle(from_a - from_b)))


def view_change_deg(
    source: np.ndarray, target: np.ndarray, pose: np.ndarray, gate_m: float
) -> float:
    """Median angle [deg] between the directions from which the two keyframes see the
    structure they match: each source point registered at `pose` (frame of the target's
    keyframe) and paired within `gate_m`, seen from the origin and from `pose`; 0 unpaired."""
    if len(source) == 0 or len(target) == 0:
        return 0.0
    moved = transform_points(pose, source)
    dist, _ = spatial.cKDTree(target).query(moved, distance_upper_bound=gate_m)
    seen = moved[np.isfinite(dist)]
    if len(seen) == 0:
        return 0.0
    return float(np.median(view_angles_deg(seen, np.zeros(2), pose[:2])))


def covisible_points(
    source: np.ndarray, target: np.ndarray, pose: np.ndarray, max_deg: float
) -> tuple[np.ndarray, np.ndarray]:
    """The source points (frame of keyframe k) and target points (frame of keyframe t) that
    both keyframes see from directions at most `max_deg` apart, k at `pose` in the frame of
    t: the parts of the structure whose returns can come from the same place in both views.

    The directions are taken from the two anchor keyframes, not from each point's own
    keyframe: a loop's clouds span a few keyframes 2 m apart, a small part of the angle at
    the ranges the sonar sees structure from.
    """
    origin_t, origin_k = np.zeros(2), np.asarray(pose[:2], dtype=np.float64)
    moved = transform_points(pose, source)
    keep_source = view_angles_deg(moved, origin_t, origin_k) <= max_deg
    keep_target = view_angles_deg(target, origin_t, origin_k) <= max_deg
    return source[keep_source], target[keep_target]
