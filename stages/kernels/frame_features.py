"""Features of one frame: CFAR detections on both polar images (paper Sec. IV.C),
shared by stage `features` (keyframes) and stage `submaps` (the frames between them).

Each image is searched along range, per beam, by `sonarmap.stages.kernels.cfar.cfar_detect_rows`
with the threshold factor and intensity floor of each range band that the recording's
calibration set (`sonarmap.stages.kernels.front_end`); every detected cell is one feature,
up to the per-image feature budget (the strongest kept).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from sonarmap.schemas.features import SONARS
from sonarmap.schemas.sonar import KeyframeImages, SonarPing
from sonarmap.stages.kernels.cfar import cfar_detect_rows
from sonarmap.stages.kernels.clutter import band_of_ranges
from sonarmap.stages.kernels.front_end import (
    BandThresholds,
    CalibrationSettings,
    calibrate_sonar,
    denoised,
)

__all__ = [
    "CfarSettings",
    "FrameDetections",
    "budget_keep",
    "detect_ping",
    "frame_detections",
    "keyframe_features",
    "self_thresholds",
]


class CfarSettings(CalibrationSettings):
    """What detection reads of config section `features` (`FeaturesConfig`)."""

    @property
    def max_features_per_keyframe_per_sonar(self) -> int | None: ...


Thresholds = Mapping[str, BandThresholds]
"""Per sonar name, the calibrated thresholds (`BandThresholds.of` each calibration entry)."""


def self_thresholds(ping: SonarPing, config: CalibrationSettings) -> BandThresholds:
    """Thresholds calibrated on this ping alone (when no recording calibration is given)."""
    doc = calibrate_sonar([ping.image], [np.asarray(ping.ranges_m)], config, ping.sonar)
    return BandThresholds.of(doc)


def detect_mask(
    ping: SonarPing, config: CalibrationSettings, thresholds: BandThresholds | None = None
) -> np.ndarray:
    """(n_ranges, n_beams) detection mask of one polar image."""
    th = thresholds if thresholds is not None else self_thresholds(ping, config)
    tau, floor = th.rows(np.asarray(ping.ranges_m))
    rank = (config.os_rank or config.train_cells_per_side) if config.method == "os" else 0
    return cfar_detect_rows(
        denoised(ping.image, th.denoise),
        config.train_cells_per_side,
        config.guard_cells_per_side,
        tau,
        floor,
        config.method,
        rank,
    )


def detect_ping(
    ping: SonarPing, config: CalibrationSettings, thresholds: BandThresholds | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """CFAR detections of one polar image (no budget); `thresholds` None: the ping
    calibrates itself.

    Returns:
        range_bin (n,), beam (n,) int64 cell indices, sorted by (range_bin, beam).
    """
    mask = detect_mask(ping, config, thresholds)
    flat = np.flatnonzero(mask).astype(np.int64)
    return flat // mask.shape[1], flat % mask.shape[1]


def budget_keep(
    range_bin: np.ndarray, beam: np.ndarray, intensity: np.ndarray, budget: int | None
) -> np.ndarray:
    """Indices kept under the budget: the strongest intensity first, ties to the nearer
    range bin, then the lower beam; returned ascending (the (range_bin, beam) order)."""
    n = range_bin.size
    if budget is None or n <= budget:
        return np.arange(n)
    order = np.lexsort((beam, range_bin, -np.asarray(intensity, np.float64)))
    return np.sort(order[:budget])


class FrameDetections:
    """A frame's feature columns, plus what the budget dropped per sonar and the
    detections per range band before it (for the calibration's measured rates)."""

    def __init__(self) -> None:
        self.parts: list[dict[str, np.ndarray]] = []
        self.dropped: dict[str, int] = {}
        self.band_detections: dict[str, np.ndarray] = {}
        self.band_rows: dict[str, np.ndarray] = {}


def frame_detections(
    frame: KeyframeImages, config: CfarSettings, thresholds: Thresholds | None = None
) -> tuple[dict[str, np.ndarray], FrameDetections]:
    """Feature columns of one frame (both sonars, horizontal rows first) and its counts.

    Returns:
        {column: (n,) array} for every column of FEATURES_SCHEMA except `sonar`, which
        is given as `sonar_index` (0 horizontal, 1 vertical); and the frame's counts.
    """
    found = FrameDetections()
    w = config.train_cells_per_side + config.guard_cells_per_side
    for s_index, sonar in enumerate(SONARS):
        ping: SonarPing = getattr(frame, sonar)
        th = (thresholds or {}).get(sonar) or self_thresholds(ping, config)
        rb, beam = detect_ping(ping, config, th)
        intensity = np.asarray(ping.image)[rb, beam].astype(np.float32)
        edges = np.asarray(th.edges_m)
        band = band_of_ranges(np.asarray(ping.ranges_m), edges)
        found.band_detections[sonar] = np.bincount(band[rb], minlength=len(edges) - 1)
        found.band_rows[sonar] = np.bincount(
            band[w : max(band.size - w, w)], minlength=len(edges) - 1
        )
        keep = budget_keep(rb, beam, intensity, config.max_features_per_keyframe_per_sonar)
        found.dropped[sonar] = int(rb.size - keep.size)
        rb, beam, intensity = rb[keep], beam[keep], intensity[keep]
        found.parts.append(
            {
                "sonar_index": np.full(len(rb), s_index, np.int64),
                "range_bin": rb,
                "beam": beam,
                "range_m": np.asarray(ping.ranges_m, np.float64)[rb],
                "angle_rad": np.asarray(ping.angles_rad, np.float64)[beam],
                "intensity": intensity,
            }
        )
    cols = {k: np.concatenate([p[k] for p in found.parts]) for k in found.parts[0]}
    found.parts = []
    n = len(cols["range_bin"])
    cols["keyframe_id"] = np.full(n, frame.keyframe_id, np.int64)
    cols["feature_id"] = np.arange(n, dtype=np.int64)
    return cols, found


def keyframe_features(
    frame: KeyframeImages, config: CfarSettings, thresholds: Thresholds | None = None
) -> dict[str, np.ndarray]:
    """Feature columns of one frame (`frame_detections`' columns, counts left out)."""
    return frame_detections(frame, config, thresholds)[0]
