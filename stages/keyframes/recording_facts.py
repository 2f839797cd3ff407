"""What stage `keyframes` reads of the whole recording, kept as one work unit per dataset.

Steps 1-2 (pair the pings, pose every pair) read the recording's whole navigation stream,
its ground truth and its tf tree: the part of the stage that no selection setting
(`SELECTION_FIELDS`) changes. Kept as a unit keyed by the dataset's content fingerprint
and the other settings, a sweep over keyframe spacing reads them once, not once a point.

The unit holds plain arrays and, as JSON bytes, what the reader said of the recording
(`describe()`, with its warnings, and `provenance()`): on a hit the stage reports what the
first read reported.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from sonarmap.schemas.recording import PoseTrack, Recording
from sonarmap.schemas.topics import SONARS
from sonarmap.stages.base import DATASET, StageInputError, Units
from sonarmap.stages.kernels.pairing import PingPairs, PosedPairs, posed_pairs
from sonarmap.stages.kernels.unit_keys import json_array, json_doc, unit_key

__all__ = ["SELECTION_FIELDS", "RecordingFacts", "cached_facts", "no_keyframe", "read_facts"]

SELECTION_FIELDS = ("spacing_m", "rotation_deg", "min_gap_s", "calibration_pairs", "submap_stride")
"""Keyframes settings that only choose among the posed pairs: not in the unit's key."""


@dataclass(frozen=True)
class RecordingFacts:
    """Steps 1-2 of a recording and what its reader said of it.

    Attributes:
        posed: every ping pair and its dead-reckoning pose (`posed_pairs`).
        truth: the ground-truth track, or None.
        mounts: T_base_sonar (4, 4) per sonar.
        provenance: where each role's topic, frame and mount came from.
        described: the reader's `describe()` (format, topics, sonars, warnings).
    """

    posed: PosedPairs
    truth: PoseTrack | None
    mounts: dict[str, np.ndarray]
    provenance: dict[str, Any]
    described: dict[str, Any]


def no_keyframe(posed: PosedPairs) -> StageInputError:
    """The refusal of a recording none of whose sonar pairs the navigation poses; where no
    ping pairs at all, how far apart the two sonars' pings are."""
    hint = ""
    h, v = posed.h_t_ns, posed.v_t_ns
    if len(posed.pairs.horizontal) == 0 and len(h) and len(v):
        right = np.clip(np.searchsorted(v, h), 1, max(len(v) - 1, 1))
        nearest = np.minimum(np.abs(v[right - 1] - h), np.abs(v[np.minimum(right, len(v) - 1)] - h))
        hint = (
            f"; the pings are a median {float(np.median(nearest)) * 1e-9:.3g} s apart, "
            "over keyframes.pair_tolerance_s"
        )
    return StageInputError(
        DATASET,
        f"no keyframe: {len(posed.pairs.horizontal)} sonar pairs ({len(h)} "
        f"horizontal, {len(v)} vertical pings), {len(posed.posed)} inside the "
        "navigation stream" + hint,
    )


STAMP_OFFSET_WARN_S = 0.25
"""A sonar's log time - header stamp further than this [s] from the navigation's is
warned of: at the 0.5 m/s of a survey, its pings posed 0.125 m along the track, more than
a voxel of the map (0.1 m)."""


STAMP_OTHER_BASE_S = 86400.0
"""An offset of log time from header stamps over a day is a driver stamping in another time
base (time since boot, GPS time), not a clock set wrong: not compared."""


def stamp_offset_warning(
    name: str, sonar: str, offset_s: float | None, navigation_offset_s: float | None
) -> str | None:
    """The warning for a sonar whose log times sit further from its header stamps than
    the navigation's do (`sonarmap.pipeline.readers.stamp_offsets`); None when they agree
    or either has no stamps."""
    if offset_s is None or navigation_offset_s is None:
        return None
    if max(abs(offset_s), abs(navigation_offset_s)) > STAMP_OTHER_BASE_S:
        return None  # stamps in another time base (since boot, GPS time): not comparable
    apart = abs(offset_s - navigation_offset_s)
    if apart <= STAMP_OFFSET_WARN_S:
        return None
    return (
        f"{name}: {sonar} sonar: its log times are {offset_s:+.3g} s from its header stamps, "
        f"the navigation's {navigation_offset_s:+.3g} s: pings are posed by log time, so if "
        f"the stamps are right they are posed {apart:.3g} s along the track from where they "
        "were taken (do the recorders' clocks differ?)"
    )


def read_facts(rec: Recording, pair_tolerance_s: float) -> RecordingFacts:
    """Read steps 1-2 from the recording (in the order whose warnings `describe` lists).

    Raises:
        StageInputError: no pair inside the navigation stream (bad data: exit 2 naming
            the recording).
    """
    posed = posed_pairs(rec, pair_tolerance_s)
    if len(posed.posed) == 0:
        raise no_keyframe(posed)
    truth = rec.ground_truth()
    mounts = {s: np.asarray(T, np.float64) for s, T in rec.mountings().items()}
    provenance = getattr(rec, "provenance", None)
    return RecordingFacts(
        posed, truth, mounts, provenance() if callable(provenance) else {}, rec.describe()
    )


def _encode(facts: RecordingFacts) -> dict[str, np.ndarray] | None:
    described, provenance = json_array(facts.described), json_array(facts.provenance)
    if described is None or provenance is None:
        return None
    p = facts.posed
    arrays = {
        "pairs_horizontal": p.pairs.horizontal,
        "pairs_vertical": p.pairs.vertical,
        "unpaired": np.array([p.pairs.unpaired_horizontal, p.pairs.unpaired_vertical], np.int64),
        "h_t_ns": p.h_t_ns,
        "v_t_ns": p.v_t_ns,
        "pose": p.pose,
        "posed": p.posed,
        "described": described,
        "provenance": provenance,
        **{f"mount_{s}": facts.mounts[s] for s in SONARS},
    }
    if facts.truth is not None:
        arrays.update(
            truth_t_ns=facts.truth.t_ns, truth_xyz_m=facts.truth.xyz_m,
            truth_rpy_rad=facts.truth.rpy_rad,
        )  # fmt: skip
    return arrays


def _decode(got: Any) -> RecordingFacts:
    unpaired = np.asarray(got["unpaired"]).tolist()
    pairs = PingPairs(
        np.asarray(got["pairs_horizontal"]), np.asarray(got["pairs_vertical"]), *unpaired
    )
    posed = PosedPairs(
        pairs, np.asarray(got["h_t_ns"]), np.asarray(got["v_t_ns"]), np.asarray(got["pose"]),
        np.asarray(got["posed"]),
    )  # fmt: skip
    truth = None
    if "truth_t_ns" in got:
        truth = PoseTrack(
            np.asarray(got["truth_t_ns"]), np.asarray(got["truth_xyz_m"]),
            np.asarray(got["truth_rpy_rad"]),
        )  # fmt: skip
    mounts = {s: np.asarray(got[f"mount_{s}"]) for s in SONARS}
    return RecordingFacts(
        posed, truth, mounts, json_doc(got["provenance"]), json_doc(got["described"])
    )


def cached_facts(
    rec: Recording, config: Any, name: str, version: int, units: Units | None
) -> RecordingFacts:
    """`read_facts`, taken from `units` when it holds them for this dataset and settings."""
    dataset = getattr(units, "dataset", "") if units is not None else ""
    if units is None or not dataset:
        return read_facts(rec, config.pair_tolerance_s)
    settings = config.model_dump(mode="json", exclude=set(SELECTION_FIELDS))
    key = unit_key(
        {"stage": name, "version": version, "unit": "recording", "dataset": dataset,
         "config": settings}
    )  # fmt: skip
    got = units.get(key)
    if got is not None:
        return _decode(got)
    facts = read_facts(rec, config.pair_tolerance_s)
    arrays = _encode(facts)
    if arrays is not None:
        units.put(key, arrays)
    return facts
