"""Poses as homogeneous transforms: (x, y, z, roll, pitch, yaw) rows [m, rad] with
R = Rz(yaw) Ry(pitch) Rx(roll) (extrinsic x-y-z, ROS RPY), shared by the stages that
register points with keyframe and frame poses (`voxelize`, `submaps`, `evaluate`)."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

__all__ = ["pose_matrices", "pose_matrix", "rotation_rpy"]


def pose_matrix(pose: np.ndarray) -> np.ndarray:
    """(n, 4, 4) transforms of (n, 6) poses x, y, z, roll, pitch, yaw (R = Rz Ry Rx)."""
    p = np.asarray(pose, np.float64).reshape(-1, 6)
    T = np.tile(np.eye(4), (len(p), 1, 1))
    T[:, :3, :3] = rotation_rpy(p[:, 3], p[:, 4], p[:, 5])
    T[:, :3, 3] = p[:, :3]
    return T


def rotation_rpy(roll_rad: np.ndarray, pitch_rad: np.ndarray, yaw_rad: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations R = Rz(yaw) Ry(pitch) Rx(roll) (extrinsic x-y-z, ROS RPY)."""
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    cy, sy = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], axis=-1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], axis=-1),
            np.stack([-sp, cp * sr, cp * cr], axis=-1),
        ],
        axis=-2,
    )


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
