"""Features of one frame: SOCA-CFAR detections on both polar images (paper Sec. IV.C),
shared by stage `features` (keyframes) and stage `submaps` (the frames between them).

Each image is searched along range, per beam, by `sonarmap.stages.kernels.cfar.cfar_detect`,
ANDed with an intensity floor; every detected cell is one feature.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from sonarmap.schemas.features import SONARS
from sonarmap.schemas.sonar import KeyframeImages, SonarPing
from sonarmap.stages.kernels.cfar import CfarMethod, cfar_detect

__all__ = ["CfarSettings", "detect_ping", "keyframe_features"]


class CfarSettings(Protocol):
    """What detection reads of config section `features` (`FeaturesConfig`)."""

    @property
    def method(self) -> CfarMethod: ...
    @property
    def train_cells_per_side(self) -> int: ...
    @property
    def guard_cells_per_side(self) -> int: ...
    @property
    def pfa(self) -> float: ...
    @property
    def os_rank(self) -> int: ...
    @property
    def intensity_floor(self) -> float: ...


def detect_ping(ping: SonarPing, config: CfarSettings) -> tuple[np.ndarray, np.ndarray]:
    """CFAR detections of one polar image.

    Returns:
        range_bin (n,), beam (n,) int64 cell indices, sorted by (range_bin, beam).
    """
    mask = cfar_detect(
        ping.image,
        config.train_cells_per_side,
        config.guard_cells_per_side,
        config.pfa,
        config.method,
        config.os_rank,
        config.intensity_floor,
    )
    flat = np.flatnonzero(mask).astype(np.int64)
    return flat // mask.shape[1], flat % mask.shape[1]


def keyframe_features(frame: KeyframeImages, config: CfarSettings) -> dict[str, np.ndarray]:
    """Feature columns of one keyframe (both sonars, horizontal rows first).

    Returns:
        {column: (n,) array} for every column of FEATURES_SCHEMA except `sonar`, which
        is given as `sonar_index` (0 horizontal, 1 vertical).
    """
    parts: list[dict[str, np.ndarray]] = []
    for s_index, sonar in enumerate(SONARS):
        ping: SonarPing = getattr(frame, sonar)
        rb, beam = detect_ping(ping, config)
        parts.append(
            {
                "sonar_index": np.full(len(rb), s_index, np.int64),
                "range_bin": rb,
                "beam": beam,
                "range_m": np.asarray(ping.ranges_m, np.float64)[rb],
                "angle_rad": np.asarray(ping.angles_rad, np.float64)[beam],
                "intensity": np.asarray(ping.image)[rb, beam].astype(np.float32),
            }
        )
    cols = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    n = len(cols["range_bin"])
    cols["keyframe_id"] = np.full(n, frame.keyframe_id, np.int64)
    cols["feature_id"] = np.arange(n, dtype=np.int64)
    return cols
