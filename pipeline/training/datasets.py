"""Simulated datasets on demand, reused when their recipe is unchanged.

`demo`, `study` and classifier training all need simulated missions. Each MCAP gets a
sidecar `<name>.recipe.json` (scene text hash, seed, mission options, simulator
version); an existing file with the same recipe is reused instead of re-simulated.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.package_data import configs_dir

if TYPE_CHECKING:
    from sonarmap.sim.config import SimConfig
    from sonarmap.sim.scene import Scene

__all__ = [
    "SCENES_DIR",
    "Simulation",
    "ensure_simulation",
    "ensure_simulations",
    "read_scene",
    "scene_path",
    "sim_config",
]

log = logging.getLogger(__name__)

SCENES_DIR = configs_dir() / "scenes"


def scene_path(name_or_path: str | Path) -> Path:
    """A scene by file path, or by name in `configs/scenes/` ("marina", "pier.yaml")."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    for candidate in (SCENES_DIR / p.name, SCENES_DIR / f"{p.name}.yaml"):
        if candidate.is_file():
            return candidate
    raise ConfigError(
        f"scene '{name_or_path}' not found (scenes: {sorted(x.stem for x in SCENES_DIR.glob('*.yaml'))})"
    )


def read_scene(path: Path) -> Scene:
    """A scene YAML, validated; bad YAML or a bad field is one ConfigError line."""
    from sonarmap.pipeline.engine.config.validation import validation_message
    from sonarmap.pipeline.engine.config.yaml_files import read_model
    from sonarmap.sim.scene import Scene, SceneError, meshes_found

    scene = read_model(
        path,
        "scene",
        Scene,
        ConfigError,
        lambda err: validation_message(Scene, err, f"scene {path}"),
        "a scene must be a YAML mapping",
    )
    # Mesh files are named relative to the scene file (`sonarmap.sim.scene.MeshObject`).
    try:
        return meshes_found(scene, path)
    except SceneError as err:
        raise ConfigError(str(err)) from err


def sim_config(
    goals: int | None,
    duration_s: float | None,
    sensor: Mapping[str, Any] | None = None,
    sonars: Mapping[str, str] | None = None,
) -> SimConfig:
    """The simulator's defaults with a mission of `goals` goals, cut after `duration_s`,
    the named sensors `sonars` ({"horizontal"/"vertical": preset or "sim-clean"},
    `sonarmap.pipeline.training.sim_sensors`; None: the clean sensor) and the sensor draw
    `sensor` (`sonarmap.sim.randomise.draw_sensor`) when given."""
    from sonarmap.pipeline.training.sim_sensors import with_sensors
    from sonarmap.sim.config import SimConfig
    from sonarmap.sim.randomise import randomised_config

    base = SimConfig() if sonars is None else with_sensors(SimConfig(), sonars)
    mission = base.mission.model_copy(
        update={"n_goals": goals or base.mission.n_goals, "duration_s": duration_s}
    )
    cfg = base.model_copy(update={"mission": mission})
    return randomised_config(cfg, sensor) if sensor is not None else cfg


def _recipe(
    scene: Path | bytes,
    seed: int,
    goals: int | None,
    duration_s: float | None,
    sensor: Mapping[str, Any] | None = None,
    sonars: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    from sonarmap.sim.version import SIM_VERSION as sim_version

    recipe = {
        "scene_sha256": hashlib.sha256(
            scene if isinstance(scene, bytes) else scene.read_bytes()
        ).hexdigest(),
        "seed": seed,
        "goals": goals,
        "duration_s": duration_s,
        "simulator": sim_version,
    }
    # Only when drawn: a default-sensor recipe (and its lock entry) stays as it was.
    if sensor is not None:
        recipe["sensor"] = json.loads(json.dumps(sensor, sort_keys=True))
    if sonars is not None:
        from sonarmap.pipeline.training.sim_sensors import sensor_recipe

        recipe["sonars"] = sensor_recipe(sonars)
    return recipe


def _is_current(out: Path, recipe: dict[str, Any]) -> bool:
    sidecar = out.with_suffix(".recipe.json")
    if out.is_file() and sidecar.is_file():
        try:
            return bool(json.loads(sidecar.read_text()) == recipe)
        except ValueError:
            pass
    return False


def ensure_simulation(
    scene: Path,
    seed: int,
    out: Path,
    *,
    goals: int | None = None,
    duration_s: float | None = None,
    progress: Callable[[int, int], None] | None = None,
    sensor: Mapping[str, Any] | None = None,
    scene_text: str | None = None,
    sonars: Mapping[str, str] | None = None,
) -> Path:
    """Simulate `scene` with `seed` into `out` unless an identical one is already there
    (`sensor`: a `sonarmap.sim.randomise.draw_sensor` draw, part of the recipe; `scene_text`: a
    generated scene, written to `scene` first when the file differs; `sonars`: named
    sensors, `sim_config`, part of the recipe)."""
    recipe = _recipe(
        scene_text.encode() if scene_text is not None else scene,
        seed,
        goals,
        duration_s,
        sensor,
        sonars,
    )
    sidecar = out.with_suffix(".recipe.json")
    if _is_current(out, recipe):
        return out
    if scene_text is not None and not (scene.is_file() and scene.read_text() == scene_text):
        scene.parent.mkdir(parents=True, exist_ok=True)
        tmp = scene.with_name(f"{scene.name}.{os.getpid()}.tmp")
        tmp.write_text(scene_text)
        tmp.replace(scene)  # atomic: a concurrent simulation reads the old or the new file
    # Only a miss pays for the simulator's imports (open3d).
    from sonarmap.pipeline.engine.errors import SourceError
    from sonarmap.pipeline.formats.simulation import write_simulation
    from sonarmap.sim.dataset import simulate

    run = simulate(read_scene(scene), sim_config(goals, duration_s, sensor, sonars), seed)
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        write_simulation(run, out, scene_yaml=scene.read_text(), progress=progress)
    except OSError as err:
        raise SourceError(f"{out}: cannot write ({err.strerror})") from err
    sidecar.write_text(json.dumps(recipe, sort_keys=True))
    return out


@dataclass(frozen=True)
class Simulation:
    """One `ensure_simulation` call: scene file, seed, output MCAP, mission options, and
    the sensor draw (None: the simulator's default sensor)."""

    scene: Path
    seed: int
    out: Path
    goals: int | None = None
    duration_s: float | None = None
    sensor: Mapping[str, Any] | None = field(default=None, compare=False, hash=False)
    scene_text: str | None = field(default=None, compare=False, repr=False)
    """A generated scene's YAML, written to `scene` only when simulating (planning
    writes nothing)."""
    sonars: Mapping[str, str] | None = field(default=None, compare=False, hash=False)
    """Named sensors per sonar (`sim_config`; None: the clean sensor, left out of the recipe)."""

    def recipe(self) -> dict[str, Any]:
        """What the recording's bytes depend on (scene sha256, seed, mission, sensor,
        simulator)."""
        scene = self.scene_text.encode() if self.scene_text is not None else self.scene
        return _recipe(scene, self.seed, self.goals, self.duration_s, self.sensor, self.sonars)

    def is_current(self) -> bool:
        """The output exists with this recipe (nothing to simulate)."""
        return _is_current(self.out, self.recipe())

    def ensure(self) -> Path:
        return ensure_simulation(
            self.scene,
            self.seed,
            self.out,
            goals=self.goals,
            duration_s=self.duration_s,
            sensor=self.sensor,
            scene_text=self.scene_text,
            sonars=self.sonars,
        )


def _ensure(sim: Simulation) -> Path:
    return sim.ensure()


def ensure_simulations(sims: Sequence[Simulation], workers: int) -> list[Path]:
    """`ensure_simulation` for each; the missing ones simulated concurrently, each in its
    own process (a simulation is one core's work; the files are the same either way).

    Args:
        sims: what to simulate, longest first (so the short ones fill in after it);
            duplicates (same output) are simulated once.
        workers: processes at most (1: one after the other, in this process).

    Returns:
        The output paths, in the order of `sims`.
    """
    missing = list({s.out: s for s in sims if not s.is_current()}.values())
    if workers > 1 and len(missing) > 1:
        from concurrent.futures import ProcessPoolExecutor
        from multiprocessing import get_context

        # spawn: the caller may hold threads (torch, progress bars) that fork would copy.
        with ProcessPoolExecutor(min(workers, len(missing)), get_context("spawn")) as pool:
            for done in pool.map(_ensure, missing):
                log.info("simulated %s", done)
    return [s.ensure() for s in sims]
