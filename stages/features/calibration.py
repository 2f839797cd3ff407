"""The features stage's second output, `calibration.json`: what the front end measured of
the recording, the thresholds it set, and, after detection, whether it flooded or starved.

Per sonar: the times of the ping pairs sampled (stage `keyframes` picks them,
`keyframes.calibration_pairs` on a grid of absolute ping time: the same sample whatever the
keyframe selection, and the same when the recording is extended or trimmed at its end),
the range band edges [m], each band's background median, fitted law and thresholds, the stated per-cell false-alarm
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
- bands whose law was borrowed from the nearest fitted band (saturated, constant or empty);
- sampled pings whose median levels differ by half again: the sensor's gain, range or
  mode changed during the dive, and one calibration does not fit both parts;
- sampled pings holding one level in every pixel (blank, saturated), left out of the
  calibration (`constant_t_ns`): a sonar pinging in air at the start of a dive, or a
  driver filling dropped pings, would otherwise set the thresholds or refuse the dive.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sonarmap.schemas.features import SONARS
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.base import StageSettingsError
from sonarmap.stages.kernels.front_end import calibrate_sonar, rounded
from sonarmap.stages.kernels.time_grid import sampled_by_time

__all__ = [
    "FLOOD_FACTOR",
    "LEVEL_STEP_FACTOR",
    "LEVEL_STEP_MIN",
    "MIN_EXPECTED",
    "calibrate",
    "calibrate_sample",
    "calibration_sample",
    "with_measurements",
    "with_pinned_bands",
]

FLOOD_FACTOR = 3.0
"""A background detection rate over 3x (or under 1/3 of) the stated rate warns."""
MIN_EXPECTED = 30.0
"""The starve check on background bands needs this many false alarms expected there."""
LEVEL_STEP_FACTOR = 1.5
LEVEL_STEP_MIN = 8.0
"""Sampled pings whose median levels differ by 1.5x and 8 levels warn (`_level_change`)."""


DEFAULT_SAMPLE = 24
"""Keyframes sampled when no ping pairs are handed over (`keyframes.calibration_pairs`'s
default)."""


def calibration_sample(
    frames: Sequence[KeyframeImages], t_ns: np.ndarray | None = None, n: int = DEFAULT_SAMPLE
) -> list[KeyframeImages]:
    """`n` keyframes on a grid of absolute time (`sampled_by_time`), for a caller with
    keyframes and no calibration sample of stage `keyframes`; `t_ns`: each frame's ping
    time when known without reading the frames (keyframes.parquet)."""
    times = np.array([f.t_ns for f in frames], np.int64) if t_ns is None else t_ns
    return [frames[int(i)] for i in sampled_by_time(times, n)]


def calibrate(
    frames: Sequence[KeyframeImages], config: Any, t_ns: np.ndarray | None = None
) -> dict[str, Any]:
    """The calibration of a sample of keyframes (`calibration_sample`), before detection.

    Raises:
        UnmodelableImages: a sonar's sampled images cannot be modelled (see `calibrate_sonar`).
    """
    return calibrate_sample(calibration_sample(frames, t_ns), config)


def calibrate_sample(picked: Sequence[KeyframeImages], config: Any) -> dict[str, Any]:
    """The calibration of the sampled ping pairs `picked` (before detection)."""
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
        constant = [_constant_level(p.image) for p in pings]
        kept = [p for p, level in zip(pings, constant, strict=True) if level is None]
        if kept and len(kept) < len(pings):
            levels = sorted({level for level in constant if level is not None})
            doc["warnings"].append(
                f"features: {sonar} sonar: {len(pings) - len(kept)} of {len(pings)} calibration"
                f" pings hold one level in every pixel ({', '.join(map(str, levels))}), left"
                " out of the calibration: a sonar not yet pinging or in air, or a driver"
                " filling dropped pings"
            )
            pings = kept  # all constant: the calibration refuses them, naming why
        entry = calibrate_sonar(
            [p.image for p in pings], [np.asarray(p.ranges_m) for p in pings], config, sonar
        ) if pings else None  # fmt: skip
        if entry is None:
            continue
        entry["sampled_t_ns"] = [int(f.t_ns) for f in picked]
        medians = [float(np.median(p.image)) for p in pings]
        entry["median_levels"] = medians
        change = _level_change(medians, [int(p.t_ns) for p in pings])
        if change:
            doc["warnings"].append(f"features: {sonar} sonar: {change}")
        if len(pings) < len(picked):
            entry["constant_t_ns"] = [
                int(f.t_ns) for f, level in zip(picked, constant, strict=True) if level is not None
            ]
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


def _level_change(medians: Sequence[float], t_ns: Sequence[int]) -> str:
    """Why the sampled pings' median levels say the sensor's settings changed ("" if not).

    A stationary background's median level moves by a few percent from ping to ping (the
    clean marina: 43-45 of 255), scenes included; a step by half again (and by more than
    `LEVEL_STEP_MIN` levels, as dark images move by whole levels) is a change of gain,
    range or mode.
    """
    if len(medians) < 2:
        return ""
    lo, hi = int(np.argmin(medians)), int(np.argmax(medians))
    low, high = medians[lo], medians[hi]
    if high < LEVEL_STEP_FACTOR * low or high - low < LEVEL_STEP_MIN:
        return ""
    t0 = min(t_ns)
    return (
        f"the sampled pings' median level runs from {low:.0f} (at {(t_ns[lo] - t0) / 1e9:.0f} s)"
        f" to {high:.0f} (at {(t_ns[hi] - t0) / 1e9:.0f} s): the sonar's gain, range or mode"
        " changed during the dive? One calibration serves the whole recording, so the pings"
        " at the other level are detected at another rate than stated"
    )


def _constant_level(image: np.ndarray) -> int | None:
    """The one level of an image whose pixels are all equal (no echo to fit), else None."""
    lo, hi = image.min(), image.max()
    return int(lo) if lo == hi else None


def with_pinned_bands(doc: dict[str, Any], pinned: Mapping[str, Any]) -> dict[str, Any]:
    """The calibration with every band's thresholds and the filter taken from `pinned`
    (`features.pinned_bands`, per sonar): the measured laws stay, to say whether the
    pinned thresholds flood or starve on this recording; the rates they expect were
    measured for other thresholds, so they are dropped.

    Raises:
        StageSettingsError: the pinned range bands are not this recording's.
    """
    out = {**doc, "sonars": {}, "measured": []}
    out["pinned"] = {**(doc.get("pinned") or {}), "bands": "features.pinned_bands"}
    for sonar, entry in (doc.get("sonars") or {}).items():
        pin = pinned[sonar]
        edges = np.asarray(entry["band_edges_m"], np.float64)
        given = np.asarray(pin.band_edges_m, np.float64)
        # the file's edges are rounded to six digits, as are this calibration's
        if edges.shape != given.shape or not np.allclose(edges, given, rtol=1e-5, atol=1e-6):
            raise StageSettingsError(
                f"features.pinned_bands: {sonar} sonar: {len(given) - 1} range bands over"
                f" {round(given[0], 3):g} to {round(given[-1], 3):g} m pinned, this recording's"
                f" are {len(edges) - 1} over {round(edges[0], 3):g} to {round(edges[-1], 3):g} m:"
                " pin a calibration"
                " of the same sonar range and features.range_bands"
            )
        bands = [
            {**b, "threshold_factor": t, "intensity_floor_levels": f,
             "expected_false_alarm_rate": None, "expected_false_alarms_per_ping": None}
            for b, t, f in zip(entry["bands"], pin.threshold_factor, pin.intensity_floor_levels,
                               strict=True)
        ]  # fmt: skip
        out["sonars"][sonar] = {
            **entry, "band_edges_m": list(pin.band_edges_m), "bands": bands,
            "denoise": pin.denoise, "expected_false_alarms_per_ping": None,
        }  # fmt: skip
    return out


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
