"""DVL samples as the vehicle's body velocity: mount rotation, lever arm, plausibility gates.

A DVL measures the velocity of its own transducer head in its own frame. The velocity of
base_link follows from the rigid-body relation v_dvl_point = v_base + omega x r, with r the
DVL's position in base_link (its lever arm) and omega the body angular rate (from the IMU):

    v_base = R_base_dvl @ v_dvl - omega_base x r_base_dvl

Gates drop only what no vehicle does: non-finite values, samples the DVL itself flags
invalid (bottom lock lost), and speeds above a configured limit well above any vehicle's.
Each gate's drops are counted, so the caller can warn with figures.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "DVL_TYPE_NAMES",
    "TWIST_TYPES",
    "GatedVelocity",
    "body_velocity",
    "dvl_velocity",
    "gate_velocity",
    "is_dvl_type",
]

DVL_TYPE_NAMES: tuple[str, ...] = ("DVL", "BottomTrack", "DVLDR", "Dvl")
"""Message names (last part of the type) of DVL drivers with a `velocity` Vector3."""

TWIST_TYPES: tuple[str, ...] = (
    "geometry_msgs/msg/TwistWithCovarianceStamped",
    "geometry_msgs/msg/TwistStamped",
)
"""Generic velocity messages some DVL drivers publish (recognised as a DVL by topic name)."""


def is_dvl_type(msgtype: str) -> bool:
    """Whether the type is a DVL driver's own message (found without configuration)."""
    return msgtype.split("/")[-1] in DVL_TYPE_NAMES


def dvl_velocity(msg: Any) -> tuple[float, float, float, bool]:
    """(vx, vy, vz, valid) of a DVL or Twist message, in the message's frame.

    `valid` is the driver's own flag where it has one (waterlinked `velocity_valid`),
    else True.
    """
    if hasattr(msg, "velocity"):
        v = msg.velocity
        valid = bool(getattr(msg, "velocity_valid", True))
    else:
        twist = msg.twist
        v = twist.twist.linear if hasattr(twist, "twist") else twist.linear
        valid = True
    return float(v.x), float(v.y), float(v.z), valid


@dataclass(frozen=True)
class GatedVelocity:
    """DVL samples that passed the gates.

    Attributes:
        keep: (n,) bool, True for the samples kept.
        dropped: {gate name: count} for every gate that dropped something.
    """

    keep: np.ndarray
    dropped: dict[str, int] = field(default_factory=dict)


def gate_velocity(v_mps: np.ndarray, valid: np.ndarray, max_speed_mps: float) -> GatedVelocity:
    """Drop non-finite, driver-invalid and implausibly fast samples (each counted once,
    by the first gate that catches it).

    Args:
        v_mps: (n, 3) velocities [m/s].
        valid: (n,) the driver's validity flag.
        max_speed_mps: a speed above this is no vehicle's motion.
    """
    v = np.asarray(v_mps, np.float64).reshape(-1, 3)
    finite = np.all(np.isfinite(v), axis=1)
    flagged = finite & ~np.asarray(valid, bool)
    speed = np.linalg.norm(np.where(finite[:, None], v, 0.0), axis=1)
    fast = finite & ~flagged & (speed > max_speed_mps)
    dropped = {
        name: int(mask.sum())
        for name, mask in (
            ("non-finite", ~finite),
            ("flagged invalid by the DVL", flagged),
            (f"faster than {max_speed_mps:g} m/s", fast),
        )
        if mask.any()
    }
    return GatedVelocity(finite & ~flagged & ~fast, dropped)


def body_velocity(
    v_dvl_mps: np.ndarray,
    R_base_dvl: np.ndarray,
    r_base_dvl_m: np.ndarray,
    omega_base_rad_s: np.ndarray,
) -> np.ndarray:
    """base_link velocity from DVL velocities (see the module docstring).

    Args:
        v_dvl_mps: (n, 3) velocities in the DVL frame [m/s].
        R_base_dvl: (3, 3) DVL orientation in base_link.
        r_base_dvl_m: (3,) DVL position in base_link [m].
        omega_base_rad_s: (n, 3) body angular rate in base_link [rad/s] at the DVL times.

    Returns:
        (n, 3) base_link velocity in base_link axes [m/s].
    """
    v = np.asarray(v_dvl_mps, np.float64).reshape(-1, 3) @ np.asarray(R_base_dvl).T
    return v - np.cross(np.asarray(omega_base_rad_s, np.float64), np.asarray(r_base_dvl_m))
