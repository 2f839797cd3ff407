"""A keyframe's detections as a work unit (`sonarmap.stages.base.Units`).

Key: sha256 of the stage's name and version, the whole `features` config section, the
thresholds detection uses per sonar (band edges, tau, floors, filter: what the
calibration set), and the digest of the keyframe's two images with their range and angle
axes. The keyframe's id is not in the key: the unit holds the feature columns without
`keyframe_id` (added back when assembled), so a keyframe with the same pings reuses it in
another recording or at another keyframe spacing.

The calibration is a unit too: keyed by the version, the config and the sampled
keyframes' digests in order, it holds `calibration.json` before detection (its JSON as
bytes), so a recording whose sample is unchanged skips the fits and the Monte Carlo.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from sonarmap.schemas.features import SONARS
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.base import Units
from sonarmap.stages.kernels.frame_features import FrameDetections, frame_detections
from sonarmap.stages.kernels.front_end import BandThresholds
from sonarmap.stages.kernels.unit_keys import array_digest, json_array, json_doc, unit_key

__all__ = ["cached_calibration", "cached_detections", "detection_base"]

_COUNTS = ("dropped", "band_detections", "band_rows")


def detection_base(
    name: str, version: int, config: Any, th: Mapping[str, BandThresholds]
) -> dict[str, Any]:
    """What every keyframe's unit key shares: stage, version, config and thresholds (which
    hold the pinned ones: a pinned run shares the units of a measured one it agrees with)."""
    return {
        "stage": name,
        "version": version,
        "config": config.model_dump(mode="json", exclude=_PINS),
        "thresholds": {s: dataclasses.asdict(t) for s, t in sorted(th.items())},
    }


_PINS = {"pinned_bands"}
"""Applied after the measurement (`with_pinned_bands`): keyed through the thresholds."""


def _frame_digest(frame: KeyframeImages) -> str:
    pings = [getattr(frame, s) for s in SONARS]
    return array_digest(*(a for p in pings for a in (p.image, p.ranges_m, p.angles_rad)))


def cached_detections(
    frame: KeyframeImages,
    config: Any,
    th: Mapping[str, BandThresholds],
    base: Mapping[str, Any],
    units: Units | None,
) -> tuple[dict[str, np.ndarray], FrameDetections]:
    """`frame_detections` of one keyframe, taken from `units` when it holds them."""
    if units is None:
        return frame_detections(frame, config, th)
    key = unit_key({**base, "frame": _frame_digest(frame)})
    got = units.get(key)
    if got is not None:
        cols = {k: np.asarray(v) for k, v in got.items() if not k.startswith("_")}
        n = len(cols["range_bin"])
        cols["keyframe_id"] = np.full(n, frame.keyframe_id, np.int64)
        found = FrameDetections()
        for i, s in enumerate(SONARS):
            found.dropped[s] = int(got["_dropped"][i])
            found.band_detections[s] = np.asarray(got[f"_band_detections_{s}"])
            found.band_rows[s] = np.asarray(got[f"_band_rows_{s}"])
        return cols, found
    cols, found = frame_detections(frame, config, th)
    stored = {k: v for k, v in cols.items() if k != "keyframe_id"}
    stored["_dropped"] = np.array([found.dropped[s] for s in SONARS], np.int64)
    for s in SONARS:
        stored[f"_band_detections_{s}"] = np.asarray(found.band_detections[s])
        stored[f"_band_rows_{s}"] = np.asarray(found.band_rows[s])
    units.put(key, stored)
    return cols, found


def cached_calibration(
    picked: Sequence[KeyframeImages],
    config: Any,
    name: str,
    version: int,
    calibrate: Callable[[Sequence[KeyframeImages], Any], dict[str, Any]],
    units: Units | None,
) -> dict[str, Any]:
    """`calibrate(picked, config)`, taken from `units` when it holds it."""
    if units is None:
        return calibrate(picked, config)
    key = unit_key(
        {
            "stage": name,
            "version": version,
            "config": config.model_dump(mode="json", exclude=_PINS),  # what is measured
            "calibration_of": [_frame_digest(f) for f in picked],
            "ids": [int(f.keyframe_id) for f in picked],  # the doc names them
        }
    )
    got = units.get(key)
    if got is not None:
        return json_doc(got["json"])
    doc = calibrate(picked, config)
    stored = json_array(doc)
    if stored is not None:
        units.put(key, {"json": stored})
    return doc
