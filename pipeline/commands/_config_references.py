"""What a config names outside itself (scene files, recordings, message definitions, a
model), checked the way a run reads them, so that `config check` does not say ok to a
config that `run` then refuses."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sonarmap.pipeline.engine.errors import ConfigError

__all__ = ["check_references"]


def check_references(config: Any) -> None:
    """Refuse (one line, naming the key) a reference the config makes that a run could not
    read: a sonar preset or beam table, a training set's scene, a recorded dataset, a
    message definition, a model folder.

    Raises:
        ConfigError: the first unusable reference.
    """
    keyframes = getattr(config, "keyframes", None)
    for side in ("horizontal_sonar", "vertical_sonar"):
        spec = getattr(keyframes, side, None) if keyframes is not None else None
        if spec:
            from sonarmap.pipeline.readers.sonar_models import load_sonar

            _named(f"keyframes.{side}", load_sonar, spec)
    if keyframes is not None and keyframes.message_definitions:
        from sonarmap.pipeline.readers.typestores import load_message_types

        _named("keyframes.message_definitions", load_message_types, keyframes.message_definitions)
    training = getattr(config, "training", None)
    if training is not None:
        from sonarmap.pipeline.training.datasets import read_scene, scene_path

        for i, item in enumerate(training.sets):
            _named(f"training.sets[{i}].scene", lambda s: read_scene(scene_path(s)), item.scene)
        for i, recorded in enumerate(training.recorded):
            path = Path(recorded).expanduser()
            if not (path.is_file() or (path / "metadata.yaml").is_file()):
                raise ConfigError(
                    f"training.recorded[{i}]: {recorded}: no recording there (an MCAP file or"
                    " a rosbag2 folder)"
                )
    from sonarmap.pipeline.readers.pinned_calibration import pin_calibration

    pin_calibration(config)  # features.calibration_from: read and checked as a run does
    classify = getattr(config, "classify", None)
    model = getattr(classify, "model", None) if classify is not None else None
    if isinstance(model, str) and model and not model.startswith("train/"):
        folder = Path(model).expanduser()
        if not (folder / "manifest.json").is_file():
            raise ConfigError(
                f"classify.model: {model}: not a model folder (`sonarmap train -o DIR` writes"
                " one, with manifest.json); or name a stored model as train/<key>"
            )


def _named(key: str, check: Any, value: Any) -> None:
    """Run `check(value)`; a refusal names the config key before its own text."""
    try:
        check(value)
    except (ConfigError, ValueError, OSError) as err:
        raise ConfigError(f"{key}: {err}") from None
