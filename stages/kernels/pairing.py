"""Pairing the two sonars' pings and posing the pairs from the navigation stream: steps
1-2 of stage `keyframes`, shared with stage `submaps`, which poses the pairs between
keyframes the same way."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sonarmap.schemas.recording import PoseTrack, Recording

__all__ = ["PingPairs", "PosedPairs", "interpolate_poses", "pair_pings", "posed_pairs"]


@dataclass(frozen=True)
class PingPairs:
    """Result of `pair_pings`.

    Attributes:
        horizontal: (k,) int64 indices into the horizontal ping times, ascending.
        vertical: (k,) int64 matching vertical indices (non-decreasing, unique).
        unpaired_horizontal, unpaired_vertical: pings left without a partner.
    """

    horizontal: np.ndarray
    vertical: np.ndarray
    unpaired_horizontal: int
    unpaired_vertical: int


def pair_pings(h_t_ns: np.ndarray, v_t_ns: np.ndarray, tolerance_ns: int) -> PingPairs:
    """Pair each horizontal ping with the nearest vertical ping within a tolerance.

    Args:
        h_t_ns: (n,) int64 ascending horizontal ping times [ns].
        v_t_ns: (m,) int64 ascending vertical ping times [ns].
        tolerance_ns: largest accepted |t_h - t_v| [ns].

    Returns:
        PingPairs; a vertical ping claimed by two horizontal pings goes to the closer one.
    """
    h = np.asarray(h_t_ns, np.int64)
    v = np.asarray(v_t_ns, np.int64)
    if len(h) == 0 or len(v) == 0:
        empty = np.zeros(0, np.int64)
        return PingPairs(empty, empty, len(h), len(v))
    right = np.clip(np.searchsorted(v, h), 0, len(v) - 1)
    left = np.clip(right - 1, 0, len(v) - 1)
    pick_left = np.abs(h - v[left]) <= np.abs(v[right] - h)
    nearest = np.where(pick_left, left, right)
    dt = np.abs(h - v[nearest])
    ok = np.flatnonzero(dt <= tolerance_ns)
    # One vertical ping per pair: keep the closest horizontal ping for each.
    order = np.lexsort((dt[ok], nearest[ok]))
    _, first = np.unique(nearest[ok][order], return_index=True)
    keep = np.sort(ok[order][first])
    return PingPairs(
        keep.astype(np.int64),
        nearest[keep].astype(np.int64),
        len(h) - len(keep),
        len(v) - len(keep),
    )


def interpolate_poses(track: PoseTrack, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poses at query times, SE(2) + depth, without extrapolation.

    Args:
        track: navigation stream (ascending t_ns).
        t_ns: (k,) int64 query times [ns].

    Returns:
        (poses, valid): (k, 6) float64 x, y, z [m], roll, pitch, yaw [rad] (NaN where
        invalid) and (k,) bool, False outside [track.t_ns[0], track.t_ns[-1]].
    """
    t = np.asarray(t_ns, np.int64)
    out = np.full((len(t), 6), np.nan)
    if len(track) == 0:
        return out, np.zeros(len(t), bool)
    valid = (t >= track.t_ns[0]) & (t <= track.t_ns[-1])
    ref = track.t_ns[0]
    tq = (t[valid] - ref).astype(np.float64)
    tt = (track.t_ns - ref).astype(np.float64)
    for c in range(3):
        out[valid, c] = np.interp(tq, tt, track.xyz_m[:, c])
        angle = np.interp(tq, tt, np.unwrap(track.rpy_rad[:, c]))
        out[valid, 3 + c] = np.arctan2(np.sin(angle), np.cos(angle))
    return out, valid


@dataclass(frozen=True)
class PosedPairs:
    """Every sonar pair of a recording and its dead-reckoning pose (steps 1-2).

    Attributes:
        pairs: the pairing (`pair_pings`).
        h_t_ns, v_t_ns: every horizontal / vertical ping time [ns].
        pose: (k, 6) dead-reckoning pose of each pair (NaN outside the navigation stream).
        posed: (p,) indices into the pairs of those inside the navigation stream.
    """

    pairs: PingPairs
    h_t_ns: np.ndarray
    v_t_ns: np.ndarray
    pose: np.ndarray
    posed: np.ndarray


def posed_pairs(rec: Recording, pair_tolerance_s: float) -> PosedPairs:
    """Steps 1-2 of stage `keyframes`: pair the pings and pose every pair (stage `submaps`
    poses the pairs between keyframes the same way)."""
    h_t, v_t = rec.ping_times_ns("horizontal"), rec.ping_times_ns("vertical")
    pairs = pair_pings(h_t, v_t, round(pair_tolerance_s * 1e9))
    pose, valid = interpolate_poses(rec.navigation(), h_t[pairs.horizontal])
    return PosedPairs(pairs, h_t, v_t, pose, np.flatnonzero(valid))
