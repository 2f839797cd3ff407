"""`features.calibration_from`: the thresholds of an earlier run's `calibration.json`,
read when the config loads into `features.pinned_bands`, so that the features key holds
the thresholds themselves (the file's path and name are not keyed). The training
section's own `training.features` is read the same way."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError

from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.engine.user_files import read_user_file

__all__ = ["CALIBRATION_MAX_BYTES", "pin_calibration"]

CALIBRATION_MAX_BYTES = 4 << 20
"""A features calibration.json is a few kB per sonar; more is not one."""

SONARS = ("horizontal", "vertical")
BAND_FIELDS = ("threshold_factor", "intensity_floor_levels")


def pin_calibration(config: BaseModel) -> BaseModel:
    """`config` with `features.pinned_bands` (and `training.features.pinned_bands`) read
    from its `calibration_from` (as is where that is unset).

    Raises:
        ConfigError: the file is missing, unreadable, not a calibration of both sonars, or
            disagrees with the settings beside it (one line naming the setting).
    """
    updates: dict[str, BaseModel] = {}
    features = getattr(config, "features", None)
    pinned = _pinned(features, "features")
    if pinned is not features:
        updates["features"] = pinned
    training = getattr(config, "training", None)
    inner = getattr(training, "features", None)
    pinned = _pinned(inner, "training.features")
    if training is not None and pinned is not inner:
        updates["training"] = training.model_copy(update={"features": pinned})
    return config.model_copy(update=updates) if updates else config


def _pinned(features: Any, section: str) -> Any:
    source = getattr(features, "calibration_from", None)
    if features is None or not source:
        return features
    where = f"{section}.calibration_from: {source}"
    try:
        data = read_user_file(Path(source).expanduser(), "calibration", ConfigError,
                              CALIBRATION_MAX_BYTES)  # fmt: skip
    except ConfigError as err:
        raise ConfigError(f"{section}.calibration_from: {err}") from None
    try:
        doc = json.loads(data, object_pairs_hook=_object)
    except RecursionError:
        raise ConfigError(f"{where}: not a calibration (JSON nested too deeply)") from None
    except (UnicodeDecodeError, ValueError) as err:
        raise ConfigError(f"{where}: not JSON ({str(err)[:120]})") from None
    sonars = doc.get("sonars") if isinstance(doc, dict) else None
    if not isinstance(sonars, dict):
        raise ConfigError(f"{where}: not a features calibration.json (no 'sonars')")
    unknown = sorted(set(sonars) - set(SONARS))
    if unknown:
        raise ConfigError(f"{where}: sonars: unknown sonar '{unknown[0]}' (horizontal, vertical)")
    bands = {s: _bands(sonars.get(s), f"{where}: sonars.{s}") for s in SONARS}
    try:
        pinned = (
            type(features)
            .model_validate({**features.model_dump(), "pinned_bands": bands})
            .pinned_bands
        )
    except ValidationError as err:
        first = err.errors()[0]
        at = ".".join(str(p) for p in first["loc"])
        message = first["msg"].removeprefix("Value error, ")
        raise ConfigError(f"{where}: {at + ': ' if at else ''}{message}") from None
    if features.pinned_bands is not None and features.pinned_bands != pinned:
        raise ConfigError(f"{where}: {section}.pinned_bands is given too, with other values")
    return features.model_copy(update={"pinned_bands": pinned})


def _object(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object; a key given twice is refused (json keeps the last one silently)."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"the key '{key}' is given twice")
        out[key] = value
    return out


def _bands(entry: Any, where: str) -> dict[str, Any]:
    """What detection reads of one sonar's entry (`front_end.BandThresholds.of`), each
    field checked for its shape (the values themselves by `PinnedBands`)."""
    if not isinstance(entry, dict) or not isinstance(entry.get("bands"), list):
        raise ConfigError(f"{where}: not calibrated in the file (no 'bands' list)")
    if not isinstance(entry.get("band_edges_m"), list):
        raise ConfigError(f"{where}.band_edges_m: expected a list of numbers")
    if not isinstance(entry.get("denoise"), str):
        raise ConfigError(f'{where}.denoise: expected the filter\'s name (e.g. "box3x3")')
    out: dict[str, Any] = {"band_edges_m": entry["band_edges_m"], "denoise": entry["denoise"]}
    for name in BAND_FIELDS:
        out[name] = []
        for i, band in enumerate(entry["bands"]):
            if not isinstance(band, dict) or name not in band:
                raise ConfigError(f"{where}.bands[{i}]: expected an object with '{name}'")
            out[name].append(band[name])
    return out
