"""The procedural training worlds of `training.procedural` as simulations.

Each world's scene is generated (`sonarmap.sim.procedural.generate_scene`); its YAML's sha256 is
in the recording's recipe like a hand-written scene's, and the file is written under
`<training.directory>/worlds/` only when the world is simulated. Each mission gets its own sensor draw (`sonarmap.sim.randomise.draw_sensor`, seeded by the
world's seed), part of its recipe.
"""

from __future__ import annotations

from pathlib import Path

from sonarmap.pipeline.training.config import ProceduralTraining, TrainingDataConfig
from sonarmap.pipeline.training.datasets import Simulation

__all__ = ["heldout_count", "procedural_simulations", "world_seeds"]


def world_seeds(proc: ProceduralTraining) -> tuple[list[int], list[int]]:
    """(training seeds, held-out validation seeds): consecutive from `base_seed`."""
    train = [proc.base_seed + k for k in range(proc.worlds)]
    val = [proc.base_seed + proc.worlds + k for k in range(proc.validation_worlds)]
    return train, val


def heldout_count(training: TrainingDataConfig) -> int:
    """How many of the default datasets (the last ones) only validate."""
    return training.procedural.validation_worlds if training.procedural is not None else 0


def procedural_simulations(training: TrainingDataConfig) -> list[Simulation]:
    """Training worlds, then the held-out ones; [] when `training.procedural` is null."""
    proc = training.procedural
    if proc is None:
        return []
    from sonarmap.sim.procedural import generate_scene, scene_yaml  # scene models: only for worlds
    from sonarmap.sim.randomise import draw_sensor

    directory = Path(training.directory)
    train, val = world_seeds(proc)
    sims = []
    for seed in train + val:
        scene = generate_scene(proc.generator, seed)
        path = directory / "worlds" / f"{scene.name}.yaml"
        sensor = draw_sensor(proc.sensor, seed) if proc.sensor is not None else None
        suffix = f"-{proc.duration_s:g}s" if proc.duration_s else ""
        out = directory / f"{scene.name}-goals{proc.goals}{suffix}.mcap"
        text = scene_yaml(scene)
        sims.append(Simulation(path, seed, out, proc.goals, proc.duration_s, sensor, text))
    return sims
