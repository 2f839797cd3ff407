"""Sanity checks on the geometry a recording supplies, applied as it is read.

Sonar pings with non-finite, negative, unordered or absurd ranges, non-finite or zero
beam directions, beam angles in no order or spanning no fan, or too few beams or range
bins cannot be mapped: they are refused with the file, topic and time. Navigation samples with a non-finite position or
orientation (or a zero quaternion) are dropped with a count; an isolated sample far
from both neighbours (a glitch) too; a jump no vehicle makes refuses the recording.
All checks are vectorised over the arrays of a ping or a whole track.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "LEVEL_LIMIT_DEG",
    "MAX_JUMP_M",
    "MAX_RANGE_M",
    "MAX_SPEED_MPS",
    "MIN_BEAMS",
    "MIN_FAN_DEG",
    "MIN_RANGE_BINS",
    "UNPOSED_SHARE",
    "beam_direction_problem",
    "navigation_doubts",
    "navigation_glitches",
    "navigation_jump",
    "ned_convention",
    "no_overlap",
    "ping_problem",
    "valid_pose_rows",
]

MIN_BEAMS = 2
MIN_RANGE_BINS = 2
"""A ping needs at least two beams and two range bins to span an area."""

MIN_FAN_DEG = 1.0
"""Imaging sonars' fans span tens of degrees; all beams within a degree is a table read in
the wrong frame (every beam projected onto one angle)."""

_RANGE_ROUNDING_M = 1e-6
"""A first range bin at 0 m less float rounding is no negative range."""

MAX_RANGE_M = 10_000.0
"""Imaging sonars reach a few hundred metres; a range beyond this is a corrupt field."""

MAX_SPEED_MPS = 50.0
MAX_JUMP_M = 50.0
"""Two consecutive navigation samples further apart than MAX_JUMP_M at more than
MAX_SPEED_MPS are not a vehicle's motion (an AUV moves at a few m/s; GPS noise of a
few metres at 10 Hz stays under the distance)."""


def beam_direction_problem(directions: np.ndarray) -> str | None:
    """Why (n, 3) beam direction vectors are unusable, or None."""
    d = np.asarray(directions, np.float64)
    if not np.isfinite(d).all():
        return (
            f"{int((~np.isfinite(d).all(axis=1)).sum())} of {len(d)} beam directions are not finite"
        )
    zero = int((np.abs(d).sum(axis=1) == 0).sum())
    if zero:
        return f"{zero} of {len(d)} beam directions are zero vectors"
    return None


def ping_problem(
    image_shape: tuple[int, ...], ranges_m: np.ndarray, angles_rad: np.ndarray
) -> str | None:
    """Why a decoded ping (image shape, (n_r,) ranges, (n_b,) angles) is unusable, or None."""
    n_r, n_b = (int(x) for x in image_shape[:2])
    if n_b < MIN_BEAMS or n_r < MIN_RANGE_BINS:
        return f"{n_r} range bins x {n_b} beams (at least {MIN_RANGE_BINS} x {MIN_BEAMS} needed)"
    r = np.asarray(ranges_m, np.float64)
    a = np.asarray(angles_rad, np.float64)
    if not np.isfinite(r).all():
        return f"{int((~np.isfinite(r)).sum())} of {len(r)} ranges are not finite"
    if r[0] < -_RANGE_ROUNDING_M:
        return f"negative range {r[0]:.4g} m"
    if not (np.diff(r) > 0).all():
        return "ranges do not increase from near to far"
    if r[-1] > MAX_RANGE_M:
        return f"range {r[-1]:.4g} m beyond {MAX_RANGE_M:g} m"
    if not np.isfinite(a).all():
        return f"{int((~np.isfinite(a)).sum())} of {len(a)} beam angles are not finite"
    step = np.sign(np.diff(a))
    if (step > 0).any() and (step < 0).any():
        turns = int(np.count_nonzero(np.diff(step[step != 0])))
        return (
            f"the beam angles rise and fall across the image ({turns} turns), so the columns"
            " are in no order of angle: a scrambled beam table, or angles not in radians"
        )
    span_deg = float(np.rad2deg(a.max() - a.min()))
    if span_deg < MIN_FAN_DEG:
        return (
            f"the {n_b} beams span {span_deg:.3g} deg of angle, not a fan: beam directions"
            " in another frame than ProjectedSonarImage's (x up, y right, z forward)?"
        )
    return None


def valid_pose_rows(xyz: np.ndarray, q_xyzw: np.ndarray) -> np.ndarray:
    """(n,) bool: a finite position and a finite, non-zero orientation quaternion."""
    xyz = np.asarray(xyz, np.float64).reshape(-1, 3)
    q = np.asarray(q_xyzw, np.float64).reshape(-1, 4)
    finite = np.asarray(np.isfinite(xyz).all(axis=1) & np.isfinite(q).all(axis=1), bool)
    with np.errstate(over="ignore", invalid="ignore"):
        norm = np.sqrt((np.where(finite[:, None], q, 0.0) ** 2).sum(axis=1))
    return finite & (norm > 1e-6) & np.isfinite(norm)


def _implausible(t_ns: np.ndarray, xyz: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(k,) bool: the step from sample a[k] to b[k] is no vehicle's motion."""
    dist = np.linalg.norm(xyz[b] - xyz[a], axis=1)
    dt = np.maximum((t_ns[b] - t_ns[a]).astype(np.float64) * 1e-9, 1e-9)
    return (dist > MAX_JUMP_M) & (dist / dt > MAX_SPEED_MPS)


def navigation_glitches(t_ns: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """(n,) bool: isolated samples far from both neighbours, which are close to each other.

    Args:
        t_ns: (n,) int64 ascending, distinct times [ns].
        xyz: (n, 3) positions [m].
    """
    n = len(t_ns)
    out = np.zeros(n, bool)
    if n < 3:
        return out
    i = np.arange(1, n - 1)
    out[1:-1] = (
        _implausible(t_ns, xyz, i - 1, i)
        & _implausible(t_ns, xyz, i, i + 1)
        & ~_implausible(t_ns, xyz, i - 1, i + 1)
    )
    return out


def navigation_jump(t_ns: np.ndarray, xyz: np.ndarray) -> int | None:
    """Index k of the first implausible step from sample k to k + 1, or None."""
    if len(t_ns) < 2:
        return None
    k = np.arange(len(t_ns) - 1)
    bad = np.flatnonzero(_implausible(t_ns, xyz, k, k + 1))
    return int(bad[0]) if len(bad) else None


LEVEL_LIMIT_DEG = 45.0
"""ROVs and AUVs keep within a few tens of degrees of level (a glider pitches about 25);
a navigation rolled or pitched past 45 degrees for most of the dive is read in another
convention."""

UNPOSED_SHARE = 0.05
"""Pings outside the navigation's span are not mapped; a few at the edges are usual."""


def navigation_doubts(
    ping_t_ns: np.ndarray, nav_t_ns: np.ndarray, rpy_rad: np.ndarray
) -> list[str]:
    """Why a navigation may map wrong though every sample is valid: over UNPOSED_SHARE of
    the horizontal pings outside its span (not mapped), or the vehicle rolled or pitched
    past LEVEL_LIMIT_DEG for over half of its samples (another convention)."""
    out = []
    if len(ping_t_ns) and len(nav_t_ns):
        early = ping_t_ns < nav_t_ns[0]
        late = ping_t_ns > nav_t_ns[-1]
        share = float(np.mean(early | late))
        if share > UNPOSED_SHARE:
            out.append(
                f"{int(np.count_nonzero(early | late))} of {len(ping_t_ns)} horizontal pings"
                f" ({100 * share:.0f} %) fall outside the navigation's span"
                f" ({int(early.sum())} before it starts, {int(late.sum())} after it ends):"
                " they are not mapped"
            )
    if len(rpy_rad):
        tilt = np.rad2deg(np.abs(np.asarray(rpy_rad, np.float64)[:, :2]))
        off = float(np.mean(tilt.max(axis=1) > LEVEL_LIMIT_DEG))
        if off > 0.5:
            roll, pitch = np.median(tilt, axis=0)
            out.append(
                f"the navigation has the vehicle rolled or pitched over {LEVEL_LIMIT_DEG:g} deg"
                f" for {100 * off:.0f} % of its samples (median |roll| {roll:.0f} deg, |pitch|"
                f" {pitch:.0f} deg): an orientation in NED/FRD read as ENU/FLU (REP 103), a"
                " quaternion written in (w, x, y, z) order, or the pose of another frame than"
                " the vehicle's? The sonars' fans are placed by it"
            )
    return out


def _ned_name(name: str) -> bool:
    return name.endswith(("_ned", "_frd")) or name in ("ned", "frd")


def ned_convention(message: object) -> tuple[bool, bool]:
    """Whether a navigation message's world frame is NED and its body frame FRD by their
    REP 105 names (`*_ned`, `*_frd`, `ned`, `frd`); (False, False) for None."""
    header = getattr(message, "header", None)
    world = str(getattr(header, "frame_id", "")).lower().rstrip("/")
    body = str(getattr(message, "child_frame_id", "")).lower().rstrip("/")
    return _ned_name(world), _ned_name(body)


def no_overlap(ping_t_ns: np.ndarray, nav_t_ns: np.ndarray) -> str | None:
    """Why no ping can be posed: the navigation spans none of them (None when some)."""
    t, n = ping_t_ns, nav_t_ns
    if len(t) == 0 or len(n) == 0 or ((t >= n[0]) & (t <= n[-1])).any():
        return None
    return (
        f"the navigation spans t_ns={int(n[0])}..{int(n[-1])} but no horizontal ping"
        f" (t_ns={int(t[0])}..{int(t[-1])}) falls inside it, so no ping can be posed"
    )
