"""The features stage's second output, `calibration.json`: what the front end measured of
the recording, the thresholds it set, and, after detection, whether it flooded or starved.

Per sonar: the keyframes sampled (`sampled_by_time`: a grid of absolute ping time, so the
sample of a recording's start is the same when it is extended or trimmed at its end), the
range band edges [m],
each band's background median, fitted law and thresholds, the stated per-cell false-alarm
rate and the expected false alarms per ping, which values were measured and which pinned
by config; then the measured detection rate on the bands called background and the
features per keyframe.

Warnings (stated rules, not fitted; "warnings" reach the run's warning lines):
- flood: the detection rate on background bands is over 3x the stated rate;
- starve: it is under a third of the stated rate, when at least 30 false alarms were
  expected there (a Poisson count 3x off its mean of 30 is over 5 sigma away);
- starve: fewer detections per keyframe and sonar (before the budget) than a third of the
  false alarms the calibration expects per ping (the thresholds pass less than the
  background alone gives);
- budget: keyframes clipped by the feature budget, with the features dropped;
- bands whose law was borrowed from the nearest fitted band (saturated, constant or empty).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from sonarmap.schemas.features import SONARS
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.kernels.front_end import calibrate_sonar, rounded

__all__ = [
    "FLOOD_FACTOR",
    "MIN_EXPECTED",
    "calibrate",
    "calibrate_sample",
    "calibration_sample",
    "sampled_by_time",
    "with_measurements",
]

FLOOD_FACTOR = 3.0
"""A background detection rate over 3x (or under 1/3 of) the stated rate warns."""
MIN_EXPECTED = 30.0
"""The starve check on background bands needs this many false alarms expected there."""


def sampled_by_time(t_ns: np.ndarray, n_sample: int) -> np.ndarray:
    """Positions of the keyframes calibrated on: those nearest to `n_sample` ticks of a grid
    of absolute ping time (ties to the earlier keyframe), unique, ascending.

    Rule: the period P is the largest power of two nanoseconds with n_sample * P at most
    the recording's span D (so the ticks cover its first D/2 to D); the ticks are the first
    n_sample multiples of P from the first keyframe's time on. Extending the recording at
    its end, or trimming it there, keeps P (unless D crosses a power of two: a 10 % change
    does so with probability about 14 %) and the ticks, so the same keyframes are sampled
    (unless a trim cuts into the ticks), the thresholds are the same and so is every
    keyframe's detection unit. With at most n_sample keyframes (or a span under n_sample
    ns), all are sampled.
    """
    t = np.asarray(t_ns, np.int64)
    n = t.size
    span = int(t[-1] - t[0]) if n else 0
    if n <= n_sample or span < n_sample:
        return np.arange(n, dtype=np.int64)
    period = 1 << ((span // n_sample).bit_length() - 1)
    first = -(-int(t[0]) // period) * period
    ticks = first + period * np.arange(n_sample, dtype=np.int64)
    right = np.clip(np.searchsorted(t, ticks), 1, n - 1)
    left = right - 1
    pick = np.where(ticks - t[left] <= t[right] - ticks, left, right)
    return np.unique(pick)


def calibration_sample(
    frames: Sequence[KeyframeImages], config: Any, t_ns: np.ndarray | None = None
) -> list[KeyframeImages]:
    """The keyframes calibrated on (`sampled_by_time`); `t_ns`: each frame's ping time
    when known without reading the frames (keyframes.parquet)."""
    times = np.array([f.t_ns for f in frames], np.int64) if t_ns is None else t_ns
    return [frames[int(i)] for i in sampled_by_time(times, config.calibration_pings)]


def calibrate(
    frames: Sequence[KeyframeImages], config: Any, t_ns: np.ndarray | None = None
) -> dict[str, Any]:
    """The calibration of a recording's keyframes (before detection); `t_ns` as in
    `calibration_sample`.

    Raises:
        UnmodelableImages: a sonar's sampled images cannot be modelled (see `calibrate_sonar`).
    """
    return calibrate_sample(calibration_sample(frames, config, t_ns), config)


def calibrate_sample(picked: Sequence[KeyframeImages], config: Any) -> dict[str, Any]:
    """The calibration of the sampled keyframes `picked` (`calibrate`)."""
    doc: dict[str, Any] = {
        "stated_false_alarm_rate_per_cell": config.false_alarm_rate_per_cell,
        "local_cfar": {
            "method": config.method,
            "train_cells_per_side": config.train_cells_per_side,
            "guard_cells_per_side": config.guard_cells_per_side,
            "pfa": config.pfa,
        },
        "pinned": {
            "intensity_floor": config.intensity_floor,
            "threshold_factor": config.threshold_factor,
        },
        "measured": sorted(
            n for n in ("intensity_floor", "threshold_factor") if getattr(config, n) is None
        ),
        "fit_quantiles": list(config.fit_quantiles),
        "sonars": {},
        "warnings": [],
    }
    for sonar in SONARS:
        pings = [getattr(f, sonar) for f in picked]
        entry = calibrate_sonar(
            [p.image for p in pings], [np.asarray(p.ranges_m) for p in pings], config, sonar
        ) if pings else None  # fmt: skip
        if entry is None:
            continue
        entry["sampled_keyframes"] = [int(f.keyframe_id) for f in picked]
        doc["sonars"][sonar] = entry
        if entry["borrowed_bands"]:
            why = "; ".join(
                f"band {b}: {entry['bands'][b]['fit']}" for b in entry["borrowed_bands"]
            )
            doc["warnings"].append(
                f"features: {sonar} sonar: {len(entry['borrowed_bands'])} range bands could not"
                f" be modelled, each assumed its nearest fitted band's law ({why})"
            )
    return doc


def with_measurements(
    doc: dict[str, Any],
    keyframes: int,
    features: dict[str, int],
    band_detections: dict[str, np.ndarray],
    band_rows: dict[str, np.ndarray],
    clipped: dict[str, tuple[int, int]],
    budget: int | None,
) -> dict[str, Any]:
    """The calibration with what detection found (module docstring: the warnings)."""
    out = {**doc, "warnings": list(doc.get("warnings") or []), "sonars": {}}
    p = float(doc["stated_false_alarm_rate_per_cell"])
    for sonar, entry in (doc.get("sonars") or {}).items():
        e = dict(entry)
        bg = np.array([b["background"] for b in e["bands"]], bool)
        cells = float((band_rows[sonar][bg]).sum()) * e["beams"] if sonar in band_rows else 0.0
        det = int(band_detections[sonar][bg].sum()) if sonar in band_detections else 0
        rate = det / cells if cells else None
        per_kf = features.get(sonar, 0) / keyframes if keyframes else 0.0
        all_det = int(band_detections[sonar].sum()) if sonar in band_detections else 0
        det_kf = all_det / keyframes if keyframes else 0.0
        n_clip, n_drop = clipped.get(sonar, (0, 0))
        e["measured"] = {
            "background_bands": np.flatnonzero(bg).tolist(),
            "background_cells": int(cells),
            "background_detections": det,
            "background_detection_rate": rounded(rate),
            "features_per_keyframe": rounded(per_kf),
            "detections_per_keyframe_before_budget": rounded(det_kf),
            "keyframes_clipped": n_clip,
            "features_dropped": n_drop,
        }
        out["sonars"][sonar] = e
        out["warnings"] += _warnings(sonar, p, rate, cells, det_kf, e, keyframes)
        if n_clip:
            out["warnings"].append(
                f"features: {sonar} sonar: the feature budget ({budget} per keyframe) clipped"
                f" {n_clip} of {keyframes} keyframes, dropping {n_drop} features"
                " (the weakest): the front end floods"
            )
    out["budget_per_keyframe_per_sonar"] = budget
    return out


def _warnings(
    sonar: str,
    p: float,
    rate: float | None,
    cells: float,
    per_kf: float,
    entry: dict[str, Any],
    keyframes: int,
) -> list[str]:
    found = []
    floods = rate is not None and rate > FLOOD_FACTOR * p
    if floods:
        found.append(
            f"features: {sonar} sonar floods: {rate:.2g} detections per cell on background"
            f" bands, over {FLOOD_FACTOR:g}x the stated false-alarm rate {p:g}"
        )
    elif rate is not None and p * cells >= MIN_EXPECTED and rate < p / FLOOD_FACTOR:
        found.append(
            f"features: {sonar} sonar starves: {rate:.2g} detections per cell on background"
            f" bands, under 1/{FLOOD_FACTOR:g} of the stated false-alarm rate {p:g}"
        )
    expected = float(entry.get("expected_false_alarms_per_ping") or 0.0)
    # Not beside a flood: a floor pinned far too low expects more false alarms than the
    # local test lets through, which is not starving.
    starved = per_kf < expected / FLOOD_FACTOR
    if not floods and keyframes and expected * keyframes >= MIN_EXPECTED and starved:
        found.append(
            f"features: {sonar} sonar starves: {per_kf:.1f} detections per keyframe, under"
            f" 1/{FLOOD_FACTOR:g} of the {expected:.1f} false alarms per ping its calibration"
            " expects from background alone"
        )
    return found
