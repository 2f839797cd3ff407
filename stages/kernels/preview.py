"""One keyframe at a time, as `sonarmap follow`'s preview maps them: a keyframe's fused
points, by the very kernels the `features` and `fuse` stages run over a whole recording,
and its pose dead-reckoned from an anchor (the keyframe rule continued from the last
keyframe is `stages.keyframes.stage.continue_selection`)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.kernels.frame_features import CfarSettings, keyframe_features
from sonarmap.stages.kernels.front_end import BandThresholds
from sonarmap.stages.kernels.fusion import FusionSettings, fuse_keyframe
from sonarmap.stages.kernels.poses import pose_matrix

__all__ = ["chained_poses", "keyframe_points"]


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
