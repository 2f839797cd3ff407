"""Simulated datasets on demand, reused when their recipe is unchanged.

`demo`, `study` and classifier training all need simulated missions. Each MCAP gets a
sidecar `<name>.recipe.json` (scene text hash, seed, mission options, simulator
version); an existing file with the same recipe is reused instead of re-simulated.
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline.engine.errors import ConfigError

if TYPE_CHECKING:
    from sim.config import SimConfig
    from sim.scene import Scene

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

SCENES_DIR = Path(__file__).resolve().parents[2] / "configs" / "scenes"


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
    from pipeline.engine.config_errors import validation_message
    from pipeline.engine.yaml_files import read_model
    from sim.scene import Scene, SceneError, meshes_found

    scene = read_model(
        path,
        "scene",
        Scene,
        ConfigError,
        lambda err: validation_message(Scene, err, f"scene {path}"),
        "a scene must be a YAML mapping",
    )
    # Mesh files are named relative to the scene file (`sim.scene.MeshObject`).
    try:
        return meshes_found(scene, path)
    except SceneError as err:
        raise ConfigError(str(err)) from err


def sim_config(goals: int | None, duration_s: float | None) -> SimConfig:
    """The simulator's defaults with a mission of `goals` goals, cut after `duration_s`."""
    from sim.config import SimConfig

    base = SimConfig()
    mission = base.mission.model_copy(
        update={"n_goals": goals or base.mission.n_goals, "duration_s": duration_s}
    )
    return base.model_copy(update={"mission": mission})


def _recipe(scene: Path, seed: int, goals: int | None, duration_s: float | None) -> dict[str, Any]:
    from sim.version import SIM_VERSION as sim_version

    return {
        "scene_sha256": hashlib.sha256(scene.read_bytes()).hexdigest(),
        "seed": seed,
        "goals": goals,
        "duration_s": duration_s,
        "simulator": sim_version,
    }


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
) -> Path:
    """Simulate `scene` with `seed` into `out` unless an identical one is already there."""
    recipe = _recipe(scene, seed, goals, duration_s)
    sidecar = out.with_suffix(".recipe.json")
    if _is_current(out, recipe):
        return out
    # Only a miss pays for the simulator's imports (open3d).
    from pipeline.engine.errors import SourceError
    from pipeline.formats.simulation import write_simulation
    from sim.dataset import simulate

    run = simulate(read_scene(scene), sim_config(goals, duration_s), seed)
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        write_simulation(run, out, scene_yaml=scene.read_text(), progress=progress)
    except OSError as err:
        raise SourceError(f"{out}: cannot write ({err.strerror})") from err
    sidecar.write_text(json.dumps(recipe, sort_keys=True))
    return out


@dataclass(frozen=True)
class Simulation:
    """One `ensure_simulation` call: scene file, seed, output MCAP, mission options."""

    scene: Path
    seed: int
    out: Path
    goals: int | None = None
    duration_s: float | None = None

    def recipe(self) -> dict[str, Any]:
        """What the recording's bytes depend on (scene sha256, seed, mission, simulator)."""
        return _recipe(self.scene, self.seed, self.goals, self.duration_s)

    def is_current(self) -> bool:
        """The output exists with this recipe (nothing to simulate)."""
        return _is_current(self.out, self.recipe())

    def ensure(self) -> Path:
        return ensure_simulation(
            self.scene, self.seed, self.out, goals=self.goals, duration_s=self.duration_s
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
