"""`features.calibration_from`: the thresholds of an earlier run's `calibration.json`,
read when the config loads into `features.pinned_bands`, so that the features key holds
the thresholds themselves (the file's path and name are not keyed)."""

from __future__ import annotations

import json
from typing import Any

from pydantic import BaseModel, ValidationError

from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.engine.user_files import read_user_file

__all__ = ["CALIBRATION_MAX_BYTES", "pin_calibration"]

CALIBRATION_MAX_BYTES = 4 << 20
"""A features calibration.json is a few kB per sonar; more is not one."""


def pin_calibration(config: BaseModel) -> BaseModel:
    """`config` with `features.pinned_bands` read from `features.calibration_from` (as is
    when that is unset).

    Raises:
        ConfigError: the file is missing, unreadable, not a calibration of both sonars, or
            disagrees with `pinned_bands` given beside it (one line naming the setting).
    """
    features = getattr(config, "features", None)
    source = getattr(features, "calibration_from", None)
    if features is None or not source:
        return config
    where = f"features.calibration_from: {source}"
    try:
        data = read_user_file(source, "calibration", ConfigError, CALIBRATION_MAX_BYTES)
    except ConfigError as err:
        raise ConfigError(f"features.calibration_from: {err}") from None
    try:
        doc = json.loads(data)
    except (UnicodeDecodeError, ValueError) as err:
        raise ConfigError(f"{where}: not JSON ({str(err)[:120]})") from None
    sonars = doc.get("sonars") if isinstance(doc, dict) else None
    if not isinstance(sonars, dict):
        raise ConfigError(f"{where}: not a features calibration.json (no 'sonars')")
    bands = {s: _bands(sonars.get(s), f"{where}: {s} sonar") for s in ("horizontal", "vertical")}
    try:
        pinned = (
            type(features)
            .model_validate({**features.model_dump(), "pinned_bands": bands})
            .pinned_bands
        )
    except ValidationError as err:
        first = err.errors()[0]
        at = ".".join(str(p) for p in first["loc"])
        raise ConfigError(f"{where}: {at}: {first['msg']}") from None
    if features.pinned_bands is not None and features.pinned_bands != pinned:
        raise ConfigError(f"{where}: features.pinned_bands is given too, with other values")
    updated = features.model_copy(update={"pinned_bands": pinned})
    return config.model_copy(update={"features": updated})


def _bands(entry: Any, where: str) -> dict[str, Any]:
    """What detection reads of one sonar's entry (`front_end.BandThresholds.of`)."""
    if not isinstance(entry, dict) or not isinstance(entry.get("bands"), list):
        raise ConfigError(f"{where}: not calibrated in the file (no 'bands')")
    try:
        return {
            "band_edges_m": list(entry["band_edges_m"]),
            "threshold_factor": [b["threshold_factor"] for b in entry["bands"]],
            "intensity_floor_levels": [b["intensity_floor_levels"] for b in entry["bands"]],
            "denoise": entry.get("denoise", "none"),
        }
    except (KeyError, TypeError) as err:
        raise ConfigError(f"{where}: a band lacks {err}") from None
