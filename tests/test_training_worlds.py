"""Procedural training worlds (issue 39, items 1 and 4): the `training` section describes
the generator, its settings reach the recordings' recipes (so the train key), validation
is held out by world, and the size rule stops as stated. The default model still trains
on the hand-written sets (`training.procedural` is off until a procedural model is shown
not to map the marina worse); these tests switch the generator on."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sonarmap.pipeline.engine.config.load import load_config
from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.graph import all_stages, extra_sections
from sonarmap.pipeline.training.model import (
    ordered_datasets,
    training_simulations,
    training_stage_for,
)
from sonarmap.pipeline.training.worlds import heldout_count, world_seeds
from sonarmap.stages.classify.size_rule import grow, macro_f1, sizes


def _training(tmp_path: Path, *overrides: str) -> Any:
    procedural = [
        base
        for base in ("training.procedural={}", "training.sets=[]")
        if not any(o.startswith(base.split("=")[0] + "=") for o in overrides)
    ]  # each setting once: a second --set of one would be refused
    config = load_config(
        all_stages(), None, [f"training.directory={tmp_path}", *procedural, *overrides],
        extra_sections(),
    )  # fmt: skip
    return config.training  # type: ignore[attr-defined]


def test_procedural_training_is_its_worlds_then_held_out_ones(tmp_path: Path) -> None:
    training = _training(tmp_path)
    proc = training.procedural
    sims = training_simulations(training)
    train, val = world_seeds(proc)
    assert [s.seed for s in sims] == train + val
    assert not set(train) & set(val)
    assert heldout_count(training) == proc.validation_worlds == len(val)
    # Each world has its own scene and its own sensor draw, both in the recipe.
    recipes = [s.recipe() for s in sims]
    assert len({r["scene_sha256"] for r in recipes}) == len(sims)
    assert len({str(r["sensor"]) for r in recipes}) == len(sims)
    # Planning writes nothing: scene files appear only when a world is simulated.
    assert not list(tmp_path.iterdir())


def test_generator_and_sensor_settings_reach_every_recipe(tmp_path: Path) -> None:
    def recipes(*overrides: str) -> list[dict]:
        return [s.recipe() for s in training_simulations(_training(tmp_path, *overrides))]

    base = recipes()
    deeper = recipes("training.procedural.generator.depth_m=[12, 15]")
    assert all(a["scene_sha256"] != b["scene_sha256"] for a, b in zip(base, deeper, strict=True))
    noisier = recipes("training.procedural.sensor.gain_db=[0, 9]")
    assert all(a["sensor"] != b["sensor"] for a, b in zip(base, noisier, strict=True))
    assert all("sensor" not in r for r in recipes("training.procedural.sensor=null"))
    assert recipes("training.procedural=null") == []
    moved = recipes("training.procedural.base_seed=2000")
    assert {r["seed"] for r in moved}.isdisjoint({r["seed"] for r in base})


@pytest.mark.parametrize(
    "override",
    [
        "training.procedural.worlds=0",
        "training.procedural.validation_worlds=0",
        "training.procedural.generator.depth_m=[15, 4]",
        "training.procedural.sensor.noise_mean_level=[50, 2]",
        "training.procedural.sensor.reflectivity_share=1.5",
        "training.procedural.goals=0",
    ],
)
def test_bad_training_settings_are_refused_with_the_field(tmp_path: Path, override: str) -> None:
    with pytest.raises(ConfigError, match=r"training\.procedural"):
        _training(tmp_path, override)


def test_held_out_worlds_come_last_after_recorded_ones_and_are_named_apart() -> None:
    training = _training(Path("/nonexistent-training-dir"))
    paths = [Path(f"w{i}.mcap") for i in range(5)]
    ordered, k = ordered_datasets(paths, training.model_copy(update={}))
    assert k == 2 and ordered[-2:] == paths[-2:]
    stage = training_stage_for(5, heldout=2)
    names = [i.name for i in stage.inputs]
    assert names[:2] == ["keyframes_0.frames", "features_0.features"]
    assert names[-2:] == ["val_keyframes_4.frames", "val_features_4.features"]
    assert sum(n.startswith("val_") for n in names) == 4


def test_macro_f1_averages_over_classes_with_support() -> None:
    assert macro_f1([[5, 0], [0, 5]]) == 1.0
    # class 0: P = 1, R = 0.5, F1 = 2/3; class 1: P = 0.5, R = 1, F1 = 2/3; class 2 unseen.
    assert macro_f1([[1, 1, 0], [0, 1, 0], [0, 0, 0]]) == pytest.approx(2 / 3)


class _Rule:
    grow_step_datasets = 2
    grow_min_gain_f1 = 0.01
    grow_patience = 2


def _run_rule(f1_by_size: dict[int, float], n: int) -> tuple[int, dict]:
    dataset = np.repeat(np.arange(n), 3)
    trained: list[int] = []

    def fit(mask: np.ndarray) -> Any:
        size = int(dataset[mask].max()) + 1
        trained.append(size)
        return size

    def score(size: Any) -> dict:
        hit = round(1000 * f1_by_size[size])  # symmetric: macro-F1 = hit / 1000
        return {"confusion": [[hit, 1000 - hit], [1000 - hit, hit]]}

    model, curve = grow(dataset, np.ones(len(dataset), bool), n, fit, score, _Rule())
    assert trained == [p["datasets"] for p in curve["points"]]
    assert model == curve["chosen_datasets"]
    return model, curve


def test_the_size_rule_stops_after_two_steps_without_a_point_and_keeps_the_best() -> None:
    # Doubling: each size trains from scratch, so the tried sizes grow geometrically.
    assert sizes(7, 2) == [2, 4, 7]
    assert sizes(8, 2) == [2, 4, 8]
    assert sizes(20, 1) == [1, 2, 4, 8, 16, 20]
    chosen, curve = _run_rule({2: 0.60, 4: 0.70, 8: 0.705, 16: 0.70, 20: 0.9}, 20)
    assert chosen == 4 and curve["converged"]
    assert [p["datasets"] for p in curve["points"]] == [2, 4, 8, 16]  # 20 never trained
    # Small gains that add up to a point count against the best, not the last size.
    chosen, curve = _run_rule({2: 0.60, 4: 0.605, 8: 0.612, 16: 0.615, 20: 0.62}, 20)
    assert chosen == 8 and curve["converged"]
    # Still rising at the ceiling: the largest set, flagged as not converged.
    chosen, curve = _run_rule({2: 0.5, 4: 0.6, 6: 0.7}, 6)
    assert chosen == 6 and not curve["converged"]


def test_a_sets_named_sensors_reach_its_recipe_and_file_and_a_bad_name_is_refused(
    tmp_path: Path,
) -> None:
    def sims(*overrides: str) -> list[Any]:
        config = load_config(
            all_stages(), None, [f"training.directory={tmp_path}", *overrides], extra_sections()
        )
        return training_simulations(config.training)  # type: ignore[attr-defined]

    # A clean set keeps its name and recipe (the lock's entries); a set with named sensors
    # carries the presets' image settings, in a file of its own.
    sets = (
        "training.sets=[{scene: pier, seed: 3, goals: 1},"
        " {scene: pier, seed: 3, goals: 1, sonars: {horizontal: aris1800-48}},"
        " {scene: pier, seed: 3, goals: 1,"
        " sonars: {horizontal: oculus-m750d-750khz, vertical: oculus-m1200d}}]"
    )
    clean, aris, oculus = sims(sets)
    assert clean.out.name == "pier-seed3-goals1.mcap" and "sonars" not in clean.recipe()
    assert aris.out.name == "pier-seed3-goals1-aris1800-48.mcap"
    assert oculus.out.name == "pier-seed3-goals1-oculus-m750d-750khz-oculus-m1200d.mcap"
    assert aris.recipe()["sonars"]["horizontal"]["noise_mean_level"] > 50
    assert oculus.recipe()["sonars"]["vertical"]["name"] == "oculus-m1200d"
    assert {clean.recipe()["seed"], aris.recipe()["seed"]} == {3}
    with pytest.raises(ConfigError, match=r"training\.sets\[0\]\.sonars.*atlantis"):
        sims("training.sets=[{scene: pier, seed: 3, goals: 1, sonars: {vertical: atlantis}}]")
