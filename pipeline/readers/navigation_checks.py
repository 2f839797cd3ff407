"""Navigation samples that are readable but not what a vehicle's navigation is: two poses
at one time, a position beyond any Earth-fixed frame, samples too far apart in time. Each
check returns the user's line (None when it holds); the reader warns or refuses with it."""

from __future__ import annotations

import numpy as np

__all__ = [
    "MAX_COORDINATE_M",
    "RATE_UNIT_RATIO",
    "SPARSE_NAVIGATION_S",
    "far_position",
    "rate_unit_doubt",
    "shared_times",
    "sparse_samples",
]

MAX_COORDINATE_M = 1e8
"""A navigation position further than this from its frame's origin is in no Earth-fixed
frame (UTM northings reach 1e7 m, ECEF coordinates 6.4e6 m): a corrupt or wrongly scaled
field. Beyond it, float64 keeps too few digits of the metres SLAM works in."""

SPARSE_NAVIGATION_S = 5.0
"""A navigation whose samples are this far apart (median) is warned about: a vehicle at
1 m/s moves 5 m between them and its turns there are lost to the interpolation (DVLs
report at 1-10 Hz, inertial navigation at 10-200 Hz)."""


RATE_UNIT_RATIO = 20.0
"""An IMU whose angular rates add up to this many times the turn of its own orientation
reports them in another unit (degrees per second: 57.3x); gyro noise stays far below it
once the vehicle has turned MIN_TURN_DEG."""
MIN_TURN_DEG = 90.0


def rate_unit_doubt(t_ns: np.ndarray, q_xyzw: np.ndarray, w: np.ndarray) -> str | None:
    """Why an IMU's angular rates (n, 3) disagree with its orientations (n, 4) at times
    `t_ns` by a unit, or None (also when it turned too little to tell)."""
    from scipy.spatial.transform import Rotation

    if len(t_ns) < 3:
        return None
    dt = np.diff(np.asarray(t_ns, np.int64)) * 1e-9
    r = Rotation.from_quat(q_xyzw)
    turned = np.linalg.norm((r[:-1].inv() * r[1:]).as_rotvec(), axis=1)
    integrated = np.linalg.norm(0.5 * (w[:-1] + w[1:]), axis=1) * dt
    if np.rad2deg(turned.sum()) < MIN_TURN_DEG:
        return None
    ratio = float(integrated.sum() / turned.sum())
    if ratio < RATE_UNIT_RATIO:
        return None
    return (
        f"its angular rates add up to {ratio:.0f}x the turn its own orientation makes:"
        " degrees per second, not radians (sensor_msgs/Imu's unit)? The DVL's lever-arm"
        " correction uses them"
    )


def far_position(where: str, rows: np.ndarray) -> str | None:
    """(n, 8) rows (t_ns, x, y, z, quaternion): the first position over MAX_COORDINATE_M."""
    far = np.abs(rows[:, 1:4]).max(axis=1, initial=0.0) > MAX_COORDINATE_M
    if not far.any():
        return None
    k = int(np.flatnonzero(far)[0])
    return (
        f"{where}: navigation position {np.abs(rows[k, 1:4]).max():.3g} m from its frame's "
        f"origin at t_ns={int(rows[k, 0])}, beyond any Earth-fixed frame "
        f"({MAX_COORDINATE_M:g} m): a corrupt or wrongly scaled field"
    )


def shared_times(where: str, rows: np.ndarray) -> str | None:
    """Samples sharing a timestamp with another at a different pose: only the first of
    each time is used (`pose_track_rows`), so the navigation is ambiguous there. Exact
    repeats (a recorder writing a sample twice) pass."""
    order = np.lexsort((np.arange(len(rows)), rows[:, 0]))
    t, values = rows[order, 0], rows[order, 1:]
    differs = (t[1:] == t[:-1]) & np.any(values[1:] != values[:-1], axis=1)
    if not differs.any():
        return None
    return (
        f"{where}: {int(differs.sum())} of {len(rows)} navigation samples share their "
        f"timestamp with another at a different pose (first at t_ns={int(t[1:][differs][0])});"
        " the first of each is used"
    )


def sparse_samples(where: str, t_ns: np.ndarray) -> str | None:
    """Samples further apart than SPARSE_NAVIGATION_S (median of the intervals)."""
    if len(t_ns) < 3:
        return None
    step = float(np.median(np.diff(t_ns))) * 1e-9
    if step <= SPARSE_NAVIGATION_S:
        return None
    return (
        f"{where}: navigation samples {step:.3g} s apart (median; over "
        f"{SPARSE_NAVIGATION_S:g} s): poses between them are interpolated linearly, so the "
        "vehicle's turns there are lost"
    )
