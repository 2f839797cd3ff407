"""Simulated sensors: the sonar presets' image character applied to a `SimConfig`.

A preset in `configs/sonars/` may carry an `image:` block (`source`: measured or
assumed, `provenance`, the real image's `statistics` and the `simulator` settings that
reproduce them; `configs/sonars/README.md`). `with_sensors` applies a preset's settings
to the horizontal and/or vertical sonar; `sim-clean` names the simulator's own clean
sensor (the `SonarConfig` defaults). Only the image character is applied: the sim's
geometry (fan, beams, range) stays as configured (see docs/simulated-sensors.md).
`with_settings` applies `KEY=VALUE` assignments to any simulator setting. Every mistake
is one `ConfigError` line naming the preset file or the key.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sonarmap.pipeline.engine.errors import ConfigError

if TYPE_CHECKING:
    from sonarmap.sim.config import SimConfig

__all__ = [
    "ARIS_PAIR",
    "CLEAN",
    "OCULUS_PAIR",
    "SENSOR_KEYS",
    "chosen_sensors",
    "image_block",
    "sensor_names",
    "sensor_recipe",
    "sensor_settings",
    "with_sensors",
    "with_settings",
]

CLEAN = "sim-clean"
"""The simulator's clean sensor (iid Rayleigh noise, median 4): `SimConfig()`'s."""

OCULUS_PAIR = {"horizontal": "oculus-m750d-750khz", "vertical": "oculus-m1200d"}
"""The README vehicle's sonars (docs/your-vehicle.md): an M750d at 750 kHz (130 deg, as the
sim's horizontal geometry) and an M1200d at 1.2 MHz (the sim's vertical frequency)."""

ARIS_PAIR = {"horizontal": "aris1800-48", "vertical": "aris1800-48"}
"""An ARIS 1800 on both sonars: the preset whose image character was measured from the
real ARIS frames (docs/simulated-sensors.md)."""

SENSOR_KEYS = (
    "noise_mean_level",
    "noise_shape",
    "noise_corr_range",
    "noise_corr_beam",
    "noise_range_slope_db",
    "gain_db",
)
"""The `SonarConfig` settings a preset's image block sets (its `simulator:` keys)."""

_SONARS = ("horizontal", "vertical")


def _presets_dir() -> Path:
    # Not `readers.sonar_models.PRESETS_DIR`: that module loads numpy, and the demo's
    # cached run (which names its sensors) loads no heavy library.
    from sonarmap.pipeline.package_data import configs_dir

    return configs_dir() / "sonars"


def sensor_names() -> list[str]:
    """`sim-clean` and every preset with an image block, sorted."""
    presets = sorted(_presets_dir().glob("*.yaml"))
    return [CLEAN, *(p.stem for p in presets if "\nimage:" in p.read_text())]


@functools.lru_cache(maxsize=64)
def _image_block(name: str) -> dict[str, Any]:
    from sonarmap.pipeline.engine.config.yaml_files import read_yaml

    if name not in sensor_names() or name == CLEAN:
        raise ConfigError(
            f"sonar {name[:80]!r}: no simulated sensor of that name (sensors: "
            f"{', '.join(sensor_names())})"
        )
    path = _presets_dir() / f"{name}.yaml"
    block = read_yaml(path, "sonar preset", ConfigError).get("image")
    sim = block.get("simulator") if isinstance(block, dict) else None
    if not isinstance(sim, dict) or block.get("source") not in ("measured", "assumed"):
        raise ConfigError(
            f"{path}: image needs `source` (measured or assumed) and a `simulator` mapping"
        )
    unknown = sorted(set(sim) - set(SENSOR_KEYS))
    if unknown:
        raise ConfigError(
            f"{path}: image.simulator.{unknown[0]}: unknown (keys: {', '.join(SENSOR_KEYS)})"
        )
    bad = [k for k, v in sim.items() if isinstance(v, bool) or not isinstance(v, int | float)]
    if bad:
        raise ConfigError(f"{path}: image.simulator.{bad[0]} must be a number")
    return block


def image_block(name: str) -> dict[str, Any]:
    """The preset's `image:` block (checked; a copy). ConfigError: unknown or malformed."""
    import copy

    return copy.deepcopy(_image_block(name))


def sensor_settings(name: str) -> dict[str, float]:
    """The `SonarConfig` settings of sensor `name` (all of `SENSOR_KEYS`: a preset's
    omitted keys are the clean sensor's neutral values)."""
    from sonarmap.sim.config import SonarConfig

    clean = SonarConfig()
    out = {k: float(getattr(clean, k)) for k in SENSOR_KEYS}
    if name != CLEAN:
        out |= {k: float(v) for k, v in _image_block(name)["simulator"].items()}
    return out


def chosen_sensors(
    both: str | None, horizontal: str | None, vertical: str | None, default: Mapping[str, str]
) -> dict[str, str]:
    """Sensor per sonar from `--sonar` (both), `--horizontal-sonar` / `--vertical-sonar`
    (each wins over `both`) and `default` for a sonar none names; names checked."""
    out = dict(default)
    out |= {s: both for s in _SONARS if both is not None}
    out |= {s: n for s, n in (("horizontal", horizontal), ("vertical", vertical)) if n}
    for name in out.values():
        sensor_settings(name)  # an unknown or malformed sensor is a ConfigError here
    return out


def sensor_recipe(sonars: Mapping[str, str]) -> dict[str, dict[str, Any]]:
    """What a recording's bytes take from its sensors: per sonar the name and its settings
    (so a cache keyed on it misses when a preset's image block changes)."""
    return {s: {"name": n, **sensor_settings(n)} for s, n in sorted(sonars.items())}


def _validated(doc: dict[str, Any], where: str) -> SimConfig:
    from pydantic import ValidationError

    from sonarmap.pipeline.engine.config.validation import validation_message
    from sonarmap.sim.config import SimConfig

    try:
        return SimConfig.model_validate(doc)
    except ValidationError as err:
        raise ConfigError(validation_message(SimConfig, err, where)) from err


def with_sensors(cfg: SimConfig, sonars: Mapping[str, str]) -> SimConfig:
    """`cfg` with sensor `sonars[s]` on sonar s ("horizontal"/"vertical"); others kept."""
    doc = cfg.model_dump()
    for sonar, name in sonars.items():
        if sonar not in _SONARS:
            raise ConfigError(f"sonar {sonar!r}: horizontal or vertical")
        doc[sonar] |= sensor_settings(name)
    return _validated(doc, f"sensor {dict(sonars)}")


def with_settings(cfg: SimConfig, assignments: Sequence[str]) -> SimConfig:
    """`cfg` with `KEY=VALUE` assignments (dotted keys of `SimConfig`, e.g.
    `horizontal.noise_mean_level=53`; VALUE read as YAML), applied in order."""
    import yaml

    doc = cfg.model_dump()
    for item in assignments:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set {item[:80]!r}: expected KEY=VALUE")
        *parents, leaf = key.strip().split(".")
        node: Any = doc
        for depth, part in enumerate([*parents, leaf]):
            if not isinstance(node, dict) or part not in node:
                where = ".".join([*parents, leaf][:depth]) or "the simulator config"
                keys = sorted(node) if isinstance(node, dict) else []
                raise ConfigError(
                    f"--set {key[:80]}: unknown key {part[:40]!r} in {where}"
                    + (f" (keys: {', '.join(keys)})" if keys else "")
                )
            if depth < len(parents):
                node = node[part]
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError as err:
            raise ConfigError(f"--set {key[:80]}: value {text[:40]!r} is not YAML") from err
        node[leaf] = value
    return _validated(doc, "--set")
