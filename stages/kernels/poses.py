"""Poses as homogeneous transforms: (x, y, z, roll, pitch, yaw) rows [m, rad] with
R = Rz(yaw) Ry(pitch) Rx(roll) (extrinsic x-y-z, ROS RPY), shared by the stages that
register points with keyframe and frame poses (`voxelize`, `submaps`, `evaluate`)."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from sonarmap.stages.kernels.geometry import se3_from_pose

__all__ = ["pose_matrices", "pose_matrix"]


def pose_matrix(pose: np.ndarray) -> np.ndarray:
    """(n, 4, 4) transforms of (n, 6) poses x, y, z, roll, pitch, yaw (R = Rz Ry Rx)."""
    return se3_from_pose(np.asarray(pose, np.float64).reshape(-1, 6))


def pose_matrices(poses: pa.Table, prefix: str = "") -> tuple[np.ndarray, np.ndarray]:
    """Keyframe poses as 4x4 transforms.

    Args:
        poses: table with keyframe_id and `{prefix}x_m ... {prefix}yaw_rad` [m, rad].
        prefix: column prefix ("gt_" for the ground-truth columns of keyframes.parquet).

    Returns:
        keyframe ids (k,) int64 sorted ascending, and (k, 4, 4) T_world_base.
    """
    kf = np.asarray(poses.column("keyframe_id").to_numpy(), dtype=np.int64)
    pose = np.stack(
        [
            np.asarray(poses.column(prefix + c).to_numpy(zero_copy_only=False), np.float64)
            for c in ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
        ],
        axis=1,
    )
    order = np.argsort(kf, kind="stable")
    return kf[order], pose_matrix(pose)[order]
