"""One keyframe at a time, as `sonarmap follow`'s preview maps them: the keyframe rule
continued from the last keyframe, and a keyframe's fused points, by the very kernels the
`keyframes`, `features` and `fuse` stages run over a whole recording."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.kernels.frame_features import CfarSettings, keyframe_features
from sonarmap.stages.kernels.front_end import BandThresholds
from sonarmap.stages.kernels.fusion import FusionSettings, fuse_keyframe
from sonarmap.stages.kernels.poses import pose_matrix

__all__ = ["chained_poses", "continue_selection", "keyframe_points"]


def continue_selection(
    last_t_ns: int,
    last_pose: np.ndarray,
    t_ns: np.ndarray,
    poses: np.ndarray,
    spacing_m: float,
    rotation_rad: float,
    min_gap_ns: int,
) -> tuple[np.ndarray, list[str]]:
    """The keyframes among candidates after the last keyframe.

    The rule (`stages.keyframes.stage.select_keyframes`) is greedy: whether a candidate
    is kept depends only on the last keyframe kept before it. Run on the last keyframe
    followed by the candidates after it, it keeps what it keeps on the whole recording.

    Args:
        last_t_ns, last_pose: the last keyframe's time [ns] and (6,) pose.
        t_ns: (k,) ascending candidate times after `last_t_ns` [ns].
        poses: (k, 6) their poses.

    Returns:
        (indices into the candidates, reason of each).
    """
    from sonarmap.stages.keyframes.stage import select_keyframes

    t = np.concatenate([[np.int64(last_t_ns)], np.asarray(t_ns, np.int64)])
    p = np.concatenate([np.asarray(last_pose, np.float64).reshape(1, 6), poses], axis=0)
    sel, reasons = select_keyframes(t, p, spacing_m, rotation_rad, min_gap_ns)
    return sel[1:] - 1, reasons[1:]


def chained_poses(
    T_world_anchor: np.ndarray, anchor_nav_pose: np.ndarray, nav_poses: np.ndarray
) -> np.ndarray:
    """(k, 4, 4) world poses of keyframes dead-reckoned from an anchor: the navigation's
    motion since the anchor's navigation pose, applied to the anchor's world (SLAM) pose."""
    T_nav_anchor = pose_matrix(anchor_nav_pose)[0]
    return T_world_anchor @ np.linalg.inv(T_nav_anchor) @ pose_matrix(nav_poses)


def keyframe_points(
    frame: KeyframeImages,
    features: CfarSettings,
    thresholds: Mapping[str, BandThresholds],
    T_h_v: np.ndarray,
    fuse: FusionSettings,
) -> dict[str, np.ndarray]:
    """A keyframe's fused points (`fuse_keyframe` columns, horizontal sonar frame) from its
    features detected with a recording's calibrated `thresholds`."""
    feats = keyframe_features(frame, features, thresholds)
    feats["is_horizontal"] = feats["sonar_index"] == 0
    return fuse_keyframe(frame, feats, T_h_v, fuse)
