"""The files a config names (a sonar's preset or beam table, message definitions), pinned
by content: their sha256s go into `keyframes.files_sha256`, so that an edited file changes
the keys, and the units, as an edited setting does (a path alone named stale results)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pydantic import BaseModel

from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.engine.hashing import sha256_file

__all__ = ["pin_referenced_files"]


def pin_referenced_files(config: BaseModel) -> BaseModel:
    """`config` with `files_sha256` of its `keyframes` section (and of the `training`
    section's, which builds the training sets) set from the files their settings name now,
    whatever they held before: it is never the user's to set; and with the thresholds of
    `features.calibration_from` read into `features.pinned_bands`.

    Raises:
        ConfigError: a named file is not there or cannot be read (one line naming it).
    """
    from sonarmap.pipeline.readers.pinned_calibration import pin_calibration

    config = pin_calibration(config)
    updates: dict[str, BaseModel] = {}
    keyframes = getattr(config, "keyframes", None)
    if keyframes is not None and hasattr(keyframes, "files_sha256"):
        pinned = _pinned(keyframes, "keyframes")
        if pinned is not keyframes:
            updates["keyframes"] = pinned
    training = getattr(config, "training", None)
    inner = getattr(training, "keyframes", None)
    if training is not None and inner is not None and hasattr(inner, "files_sha256"):
        pinned = _pinned(inner, "training.keyframes")
        if pinned is not inner:
            updates["training"] = training.model_copy(update={"keyframes": pinned})
    return config.model_copy(update=updates) if updates else config


def _pinned(keyframes: Any, where: str) -> Any:
    files: dict[str, Path] = {}
    for side in ("horizontal", "vertical"):
        spec = getattr(keyframes, f"{side}_sonar")
        if spec is not None:
            # numpy with it: only where a sonar is named (a cached run imports none)
            from sonarmap.pipeline.readers.sonar_models import sonar_file

            files[f"{side}_sonar"] = sonar_file(spec)[0]
    for i, name in enumerate(keyframes.message_definitions):
        files[f"message_definitions[{i}]"] = Path(name)
    digests = {}
    for setting, path in files.items():
        try:
            digests[setting] = sha256_file(path)
        except OSError as err:
            raise ConfigError(
                f"{where}.{setting}: {path}: cannot be read ({err.strerror})"
            ) from None
    if digests == keyframes.files_sha256:
        return keyframes
    return keyframes.model_copy(update={"files_sha256": digests})
