"""Rigid-body helpers for the simulator: rotations, 4x4 transforms, 6-vector poses.

A pose 6-vector is (x_m, y_m, z_m, roll_rad, pitch_rad, yaw_rad) of a frame in its
parent, with R = Rz(yaw) @ Ry(pitch) @ Rx(roll) (ROS fixed-axis RPY).
"""

from __future__ import annotations

import numpy as np

__all__ = ["pose_to_matrix", "rot_rpy", "rot_x", "rot_z", "transform"]


def rot_x(a_rad: float) -> np.ndarray:
    """(3, 3) rotation about x by `a_rad`."""
    c, s = np.cos(a_rad), np.sin(a_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_z(a_rad: float) -> np.ndarray:
    """(3, 3) rotation about z by `a_rad`."""
    c, s = np.cos(a_rad), np.sin(a_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_rpy(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """(3, 3) R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    return rot_z(yaw_rad) @ ry @ rot_x(roll_rad)


def pose_to_matrix(pose: np.ndarray) -> np.ndarray:
    """(6,) pose (x, y, z, roll, pitch, yaw) -> (4, 4) homogeneous transform."""
    p = np.asarray(pose, dtype=np.float64)
    t = np.eye(4)
    t[:3, :3] = rot_rpy(p[3], p[4], p[5])
    t[:3, 3] = p[:3]
    return t


def transform(t_ab: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Apply (4, 4) `t_ab` to (n, 3) points given in frame b -> (n, 3) in frame a."""
    return points_b @ t_ab[:3, :3].T + t_ab[:3, 3]
