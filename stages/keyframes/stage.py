"""Keyframes: pair the two sonars in time, pose each pair, keep pairs by spacing.

Pure logic over arrays; the recording (a `sonarmap.schemas.recording.Recording`, bound by the
engine as the "dataset" input) supplies ping times, the navigation stream and, for the
selected keyframes only, the decoded images, so memory stays flat in mission length.

Steps:
1. Pair every horizontal ping with the nearest vertical ping within
   `pair_tolerance_s` (each vertical ping used at most once).
2. Interpolate the navigation pose at each pair's time (the horizontal ping time):
   SE(2) (x, y, yaw on the shortest arc) plus depth z, roll and pitch linearly; pairs
   outside the navigation stream are dropped, never extrapolated.
3. Keep a pair as keyframe when, since the last keyframe, at least `min_gap_s` has
   passed and the vehicle has moved `spacing_m` (3D distance) or turned `rotation_deg`
   (|delta yaw|); the first posed pair is always kept (the paper keeps keyframes every
   2 m or 4 m; the authors' rule in docs/authors-code.md section 6.2).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.schemas.keyframes import GT_POSE_COLUMNS, KEYFRAMES_SCHEMA, POSE_COLUMNS
from sonarmap.schemas.recording import Recording
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.base import UNITS_INPUT
from sonarmap.stages.kernels.pairing import (
    PingPairs,
    PosedPairs,
    interpolate_poses,
    pair_pings,
    posed_pairs,
)
from sonarmap.stages.kernels.sonar_geometry import sonar_geometry
from sonarmap.stages.kernels.time_grid import sampled_by_time
from sonarmap.stages.keyframes import STAGE
from sonarmap.stages.keyframes.config import KeyframesConfig
from sonarmap.stages.keyframes.recording_facts import (
    cached_facts,
    no_keyframe,
    stamp_offset_warning,
)
from sonarmap.stages.keyframes.recording_name import path_free

__all__ = [
    "STAGE",
    "KeyframesConfig",
    "PingPairs",
    "PosedPairs",
    "continue_selection",
    "interpolate_poses",
    "pair_pings",
    "posed_pairs",
    "select_keyframes",
]


log = logging.getLogger(__name__)


def select_keyframes(
    t_ns: np.ndarray, poses: np.ndarray, spacing_m: float, rotation_rad: float, min_gap_ns: int
) -> tuple[np.ndarray, list[str]]:
    """Keyframe selection by travel / turn since the last keyframe.

    Args:
        t_ns: (k,) int64 ascending candidate times [ns].
        poses: (k, 6) x, y, z, roll, pitch, yaw of each candidate.
        spacing_m: travel threshold [m].
        rotation_rad: |yaw change| threshold [rad].
        min_gap_ns: minimum time between keyframes [ns].

    Returns:
        (indices of the selected candidates, reason per keyframe: "first",
        "translation" or "rotation").
    """
    if len(t_ns) == 0:
        return np.zeros(0, np.int64), []
    chosen, reasons = [0], ["first"]
    last = 0
    for i in range(1, len(t_ns)):
        if t_ns[i] - t_ns[last] < min_gap_ns:
            continue
        moved = float(np.linalg.norm(poses[i, :3] - poses[last, :3]))
        dyaw = float(np.abs(np.angle(np.exp(1j * (poses[i, 5] - poses[last, 5])))))
        if moved >= spacing_m or dyaw >= rotation_rad:
            chosen.append(i)
            reasons.append("translation" if moved >= spacing_m else "rotation")
            last = i
    return np.asarray(chosen, np.int64), reasons


def continue_selection(
    last_t_ns: int,
    last_pose: np.ndarray,
    t_ns: np.ndarray,
    poses: np.ndarray,
    spacing_m: float,
    rotation_rad: float,
    min_gap_ns: int,
) -> tuple[np.ndarray, list[str]]:
    """The keyframes among candidates after the last keyframe.

    The rule (`select_keyframes`) is greedy: whether a candidate
    is kept depends only on the last keyframe kept before it. Run on the last keyframe
    followed by the candidates after it, it keeps what it keeps on the whole recording.

    Args:
        last_t_ns, last_pose: the last keyframe's time [ns] and (6,) pose.
        t_ns: (k,) ascending candidate times after `last_t_ns` [ns].
        poses: (k, 6) their poses.

    Returns:
        (indices into the candidates, reason of each).
    """
    t = np.concatenate([[np.int64(last_t_ns)], np.asarray(t_ns, np.int64)])
    p = np.concatenate([np.asarray(last_pose, np.float64).reshape(1, 6), poses], axis=0)
    sel, reasons = select_keyframes(t, p, spacing_m, rotation_rad, min_gap_ns)
    return sel[1:] - 1, reasons[1:]


def _table(
    t_h: np.ndarray,
    t_v: np.ndarray,
    h_idx: np.ndarray,
    v_idx: np.ndarray,
    pose: np.ndarray,
    gt: np.ndarray | None,
    reasons: list[str],
) -> pa.Table:
    n = len(t_h)
    cols: dict[str, Any] = {
        "keyframe_id": np.arange(n, dtype=np.int64),
        "t_ns": t_h,
        "t_vertical_ns": t_v,
        "ping_index_horizontal": h_idx,
        "ping_index_vertical": v_idx,
    }
    for c, name in enumerate(POSE_COLUMNS):
        cols[name] = pose[:, c]
    for c, name in enumerate(GT_POSE_COLUMNS):
        values = None if gt is None else gt[:, c]
        cols[name] = pa.array(
            values if values is not None else [None] * n, pa.float64(), from_pandas=True
        )
    cols["reason"] = pa.array(reasons, pa.string())
    return pa.table(cols, schema=KEYFRAMES_SCHEMA)


def _frames(
    rec: Recording,
    t_h: np.ndarray,
    t_v: np.ndarray,
    h_idx: np.ndarray,
    v_idx: np.ndarray,
    ids: np.ndarray | None = None,
    labels: bool = True,
) -> Iterator[KeyframeImages]:
    """The pairs' images, decoded as they are read; `ids`: each pair's id (None: 0, 1, ...)."""
    pairs = zip(
        rec.pings("horizontal", h_idx, labels=labels),
        rec.pings("vertical", v_idx, labels=labels),
        strict=True,
    )
    for k, (hp, vp) in enumerate(pairs):
        yield KeyframeImages(
            int(k if ids is None else ids[k]), int(t_h[k]), hp, vp,
            {"pair_dt_s": float(t_v[k] - t_h[k]) * 1e-9},
        )  # fmt: skip


def _calibration_frames(
    rec: Recording, posed: PosedPairs, n_sample: int
) -> Iterator[KeyframeImages]:
    """The ping pairs the front end calibrates on: the posed pairs nearest to a grid of
    absolute time (`sampled_by_time`), whatever the keyframe selection; each carries its
    horizontal ping index as its id."""
    pairs, h_t, v_t, cand = posed.pairs, posed.h_t_ns, posed.v_t_ns, posed.posed
    pick = cand[sampled_by_time(h_t[pairs.horizontal[cand]], n_sample)]
    h_idx, v_idx = pairs.horizontal[pick], pairs.vertical[pick]
    return _frames(rec, h_t[h_idx], v_t[v_idx], h_idx, v_idx, ids=h_idx, labels=False)


def run(config: KeyframesConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    """Stage entry point: {"dataset": Recording, optionally the engine's "units"} ->
    keyframes, frames, calibration_frames, sensors, scene_mesh."""
    rec: Recording = inputs["dataset"]
    facts = cached_facts(rec, config, STAGE.name, STAGE.version, inputs.get(UNITS_INPUT))
    posed = facts.posed
    h_t, v_t, pairs, pose, cand = posed.h_t_ns, posed.v_t_ns, posed.pairs, posed.pose, posed.posed
    t_pair = h_t[pairs.horizontal]
    sel, reasons = select_keyframes(
        t_pair[cand],
        pose[cand],
        config.spacing_m,
        np.deg2rad(config.rotation_deg),
        round(config.min_gap_s * 1e9),
    )
    if len(sel) == 0:
        # Bad data, not a bug: the engine reports it as exit 2 naming the recording.
        raise no_keyframe(posed)
    k = cand[sel]
    log.info(
        "%s: %d/%d horizontal pings paired (%d horizontal, %d vertical unpaired), "
        "%d pairs outside the navigation stream, %d keyframes",
        rec.name,
        len(pairs.horizontal),
        len(h_t),
        pairs.unpaired_horizontal,
        pairs.unpaired_vertical,
        len(pairs.horizontal) - len(cand),
        len(k),
    )
    h_idx, v_idx = pairs.horizontal[k], pairs.vertical[k]
    t_h, t_v = h_t[h_idx], v_t[v_idx]
    truth = facts.truth
    gt = None
    if truth is not None:
        gt, _ = interpolate_poses(truth, t_h)
    sensors: dict[str, Any] = {
        s: {"T_base_sonar": np.asarray(facts.mounts[s], np.float64).round(12).tolist()}
        for s in ("horizontal", "vertical")
    }
    # Where each role's topic, frame and mount came from (recording, config or default).
    described = dict(facts.described)
    path = str(described.get("path") or "")  # the path the warnings were written with
    warnings = [path_free(str(w), path) for w in described.get("warnings") or []]
    for s, idx in (("horizontal", h_idx), ("vertical", v_idx)):
        ping = next(iter(rec.pings(s, idx[:1], labels=False)))  # the first keyframe's
        sensors[s].update(sonar_geometry(ping, (described.get("sonars") or {}).get(s)))
        offset = getattr(rec, "stamp_offset_s", lambda *_: None)(s, ping.t_ns)
        line = stamp_offset_warning(rec.name, s, offset, described.get("navigation_stamp_offset_s"))
        if line is not None:
            log.warning(line)
            warnings.append(path_free(line, rec.name))
    described["warnings"] = warnings
    sensors.update(
        provenance=facts.provenance,
        has_ground_truth=truth is not None,
        has_labels=bool(rec.has_labels),
        source={k2: v for k2, v in described.items() if k2 not in ("path", "sonars")},
        pairing={
            "horizontal_pings": len(h_t),
            "vertical_pings": len(v_t),
            "pairs": len(pairs.horizontal),
            "unpaired_horizontal": pairs.unpaired_horizontal,
            "unpaired_vertical": pairs.unpaired_vertical,
            "pairs_outside_navigation": int(len(pairs.horizontal) - len(cand)),
            "keyframes": len(k),
        },
    )
    return {
        "keyframes": _table(t_h, t_v, h_idx, v_idx, pose[k], gt, reasons),
        "frames": _frames(rec, t_h, t_v, h_idx, v_idx),
        "calibration_frames": _calibration_frames(rec, posed, config.calibration_pairs),
        "sensors": sensors,
        "scene_mesh": rec.attachments().get("scene.ply"),
    }
