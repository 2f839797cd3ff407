"""Depth below the surface from what vehicles publish.

- `sensor_msgs/FluidPressure` (a Bar30 through mavros or its own driver): absolute
  pressure [Pa]; depth = (p - p_surface) / (rho g).
- any message with a `depth` field [m, positive down] (bar30_depth, many DVL drivers);
- Odometry / PoseStamped / PoseWithCovarianceStamped: depth = -z (REP 103, z up).

The surface pressure comes from config, else from the median of the first seconds of
the recording when asked (the vehicle at the surface), else one standard atmosphere.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = [
    "ABOVE_SURFACE_M",
    "FLUID_PRESSURE_TYPE",
    "STANDARD_ATMOSPHERE_PA",
    "UNCOVERED_SHARE",
    "depth_doubts",
    "depth_kind",
    "depth_value",
    "pressure_depth",
    "surface_pressure",
]

FLUID_PRESSURE_TYPE = "sensor_msgs/msg/FluidPressure"
STANDARD_ATMOSPHERE_PA = 101_325.0


def depth_kind(msgtype: str, msg: Any) -> str | None:
    """How a message carries depth: "pressure", "depth" or "pose"; None when it does not."""
    if msgtype == FLUID_PRESSURE_TYPE or hasattr(msg, "fluid_pressure"):
        return "pressure"
    if hasattr(msg, "depth"):
        return "depth"
    pose = getattr(msg, "pose", None)
    if pose is not None and (hasattr(pose, "position") or hasattr(pose, "pose")):
        return "pose"
    return None


def depth_value(msg: Any, kind: str) -> float:
    """The raw value of one message: pressure [Pa], depth [m] or -z [m]."""
    if kind == "pressure":
        return float(msg.fluid_pressure)
    if kind == "depth":
        return float(msg.depth)
    pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
    return -float(pose.position.z)


def pressure_depth(
    pressure_pa: np.ndarray, surface_pa: float, density_kg_m3: float, gravity_m_s2: float
) -> np.ndarray:
    """Depth [m, positive down] of absolute pressures [Pa] (hydrostatic)."""
    return (np.asarray(pressure_pa, np.float64) - surface_pa) / (density_kg_m3 * gravity_m_s2)


def surface_pressure(t_ns: np.ndarray, pressure_pa: np.ndarray, first_s: float) -> float:
    """Median pressure of the first `first_s` seconds (the vehicle at the surface)."""
    t = np.asarray(t_ns, np.int64)
    early = t <= t[0] + round(first_s * 1e9)
    return float(np.median(np.asarray(pressure_pa, np.float64)[early]))


ABOVE_SURFACE_M = 0.5
"""A vehicle whose median depth is over half a metre above the surface (more than waves
and the weather's surface pressure explain) has a depth of the wrong sign or reference."""
UNCOVERED_SHARE = 0.1
"""Depth samples ending (or starting) over a tenth of the navigation's span away from it."""


def depth_doubts(t_ns: np.ndarray, depth_m: np.ndarray, nav_t_ns: np.ndarray) -> list[str]:
    """Why a depth track (positive down) looks wrong for navigation spanning `nav_t_ns`:
    the vehicle above the surface for most of the dive, or samples covering only part of
    the navigation (`np.interp` holds the first / last value outside them)."""
    out = []
    median = float(np.median(depth_m))
    if median < -ABOVE_SURFACE_M:
        out.append(
            f"the depth puts the vehicle {-median:.3g} m above the surface (median): a depth"
            " positive down published as z up (an NED pose), a depth message of the other"
            " sign, or gauge pressure (set keyframes.surface_pressure_pa: 0)? Every pose's"
            " z is taken from it"
        )
    span = float(nav_t_ns[-1] - nav_t_ns[0])
    before = max(0.0, float(t_ns[0] - nav_t_ns[0]))
    after = max(0.0, float(nav_t_ns[-1] - t_ns[-1]))
    if span > 0 and (before + after) > UNCOVERED_SHARE * span:
        out.append(
            f"depth samples cover {100 * (1 - (before + after) / span):.0f} % of the"
            f" navigation's {span / 1e9:.0f} s ({before / 1e9:.0f} s missing at the start,"
            f" {after / 1e9:.0f} s at the end): poses there hold the nearest depth sample's"
        )
    return out
