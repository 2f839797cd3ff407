"""Navigation messages -> `PoseTrack`, and DVL + IMU + depth dead reckoning.

Dead reckoning follows the authors' vehicle (docs/authors-code.md section 6.7):
body-frame DVL velocity, gated at `dvl_max_velocity_mps` (a gated sample reuses the last
good velocity), integrated with the trapezoid rule in x and y only, rotated by the IMU
yaw made relative to its first sample; roll and pitch from the IMU; z = -depth (REP 103,
z up). The IMU is assumed mounted aligned with base_link (the authors' -90 deg roll
`imu_pose` is a property of their vehicle, not of the recipe).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from sonarmap.schemas.recording import PoseTrack
from sonarmap.stages.kernels.geometry import rpy_from_quat

__all__ = [
    "FLU_TO_FRD",
    "NAV_TYPES",
    "NED_TO_ENU",
    "dead_reckon",
    "enu_flu",
    "nav_pose",
    "ned_note",
    "pose_track",
    "pose_track_rows",
]

NAV_TYPES: tuple[str, ...] = (
    "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
)


def nav_pose(msg: Any) -> tuple[float, float, float, float, float, float, float]:
    """Position and orientation (x, y, z, qx, qy, qz, qw) of any NAV_TYPES message."""
    pose = msg.pose
    if hasattr(pose, "pose"):  # Odometry / PoseWithCovarianceStamped
        pose = pose.pose
    p, o = pose.position, pose.orientation
    return (p.x, p.y, p.z, o.x, o.y, o.z, o.w)


def pose_track(samples: Iterable[tuple[int, Any]]) -> PoseTrack:
    """(t_ns, nav message) samples -> PoseTrack sorted by time, duplicate times dropped."""
    return pose_track_rows([(t, *nav_pose(m)) for t, m in samples])


def pose_track_rows(
    rows: Sequence[tuple[float, ...]], world_ned: bool = False, body_frd: bool = False
) -> PoseTrack:
    """(t_ns, x, y, z, qx, qy, qz, qw) rows -> PoseTrack (as `pose_track`); a world frame in
    NED or a body frame in FRD (REP 105) converted to the project's ENU / FLU (REP 103)."""
    if not rows:
        return PoseTrack(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
    t = np.array([r[0] for r in rows], np.int64)
    v = np.array([r[1:] for r in rows], np.float64)
    t, first = np.unique(t, return_index=True)
    xyz, q = v[first, :3], v[first, 3:]
    if world_ned or body_frd:
        xyz, q = enu_flu(xyz, q, world_ned, body_frd)
    return PoseTrack(t, xyz, rpy_from_quat(q))


NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""v_enu = NED_TO_ENU v_ned (x, y swapped, z negated)."""
FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])
"""v_frd = FLU_TO_FRD v_flu (y and z negated)."""


def enu_flu(
    xyz: np.ndarray, q_xyzw: np.ndarray, world_ned: bool, body_frd: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Positions (n, 3) and orientations (n, 4) in NED and/or FRD -> ENU and FLU:
    p_enu = C p_ned, R_enu_flu = C R_ned_frd D (C = NED_TO_ENU, D = FLU_TO_FRD)."""
    from scipy.spatial.transform import Rotation

    r = Rotation.from_quat(q_xyzw)
    if world_ned:
        xyz = xyz @ NED_TO_ENU.T
        r = Rotation.from_matrix(NED_TO_ENU) * r
    if body_frd:
        r = r * Rotation.from_matrix(FLU_TO_FRD)
    return xyz, r.as_quat()


def ned_note(world_ned: bool, body_frd: bool) -> str:
    """The line that says a navigation was converted from NED / FRD by its frames' names."""
    named = " and ".join(
        n for n, on in (("NED (world)", world_ned), ("FRD (body)", body_frd)) if on
    )
    return (
        f"its frames are {named} by REP 105's names (*_ned, *_frd): converted to ENU / FLU"
        " (REP 103), as sonarmap maps; rename the frames if they are not"
    )


def dead_reckon(
    dvl_t_ns: np.ndarray,
    dvl_v_mps: np.ndarray,
    imu_t_ns: np.ndarray,
    imu_q_xyzw: np.ndarray,
    depth_t_ns: np.ndarray,
    depth_m: np.ndarray,
    max_velocity_mps: float,
) -> PoseTrack:
    """Planar DVL/IMU dead reckoning with depth (docs/authors-code.md section 6.7).

    Args:
        dvl_t_ns: (n,) int64 DVL times [ns], ascending.
        dvl_v_mps: (n, 3) body-frame velocity [m/s] (x forward, y left).
        imu_t_ns: (m,) int64 IMU times [ns], ascending.
        imu_q_xyzw: (m, 4) IMU orientation quaternions.
        depth_t_ns: (k,) int64 depth times [ns]; may be empty (z = 0 then).
        depth_m: (k,) depth below the surface [m], positive down.
        max_velocity_mps: a sample with any |component| above it reuses the last good one.

    Returns:
        PoseTrack at the DVL times within the IMU's time span.
    """
    keep = (dvl_t_ns >= imu_t_ns[0]) & (dvl_t_ns <= imu_t_ns[-1])
    t = dvl_t_ns[keep]
    v = np.asarray(dvl_v_mps, np.float64)[keep, :2]
    # Velocity gate: forward-fill the last good sample (zero before the first good one).
    good = np.all(np.abs(np.asarray(dvl_v_mps)[keep]) <= max_velocity_mps, axis=1)
    last_good = np.maximum.accumulate(np.where(good, np.arange(len(t)), -1))
    v = np.where((last_good >= 0)[:, None], v[np.maximum(last_good, 0)], 0.0)
    # Attitude at the DVL times; yaw relative to the first IMU sample.
    rpy = rpy_from_quat(np.asarray(imu_q_xyzw, np.float64).reshape(-1, 4))
    yaw = np.unwrap(rpy[:, 2]) - rpy[0, 2]
    att = np.stack([np.interp(t, imu_t_ns, c) for c in (rpy[:, 0], rpy[:, 1], yaw)], axis=1)
    # Trapezoid propagation of the body velocity rotated by the planar yaw.
    dt = np.diff(t).astype(np.float64) * 1e-9
    v_mean = 0.5 * (v[1:] + v[:-1])
    c, s = np.cos(att[1:, 2]), np.sin(att[1:, 2])
    step = np.stack([c * v_mean[:, 0] - s * v_mean[:, 1], s * v_mean[:, 0] + c * v_mean[:, 1]], 1)
    xy = np.vstack([np.zeros((1, 2)), np.cumsum(step * dt[:, None], axis=0)])
    if len(depth_t_ns):
        z = -np.interp(t, depth_t_ns, np.asarray(depth_m, np.float64))
    else:
        z = np.zeros(len(t))
    att[:, 2] = np.arctan2(np.sin(att[:, 2]), np.cos(att[:, 2]))
    return PoseTrack(t.astype(np.int64), np.column_stack([xy, z]), att)
