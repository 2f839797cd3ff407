"""The model shipped in `configs/model` is the one the default `training` section gives.

A fresh clone plans the default model's key from the shipped lock, without simulating
the training scenes; if a change to a scene, the simulator, a stage version or a setting
moves that key, new users silently simulate and train for minutes again. This test
catches that in CI: run `sonarmap train --ship` and commit `configs/model`.
"""

from __future__ import annotations

import json
from pathlib import Path

from sonarmap.pipeline.engine.config.load import load_config
from sonarmap.pipeline.graph import all_stages, extra_sections
from sonarmap.pipeline.training.model import plan_training, training_simulations
from sonarmap.pipeline.training.model_cache import model_cache
from sonarmap.pipeline.training.shipped import (
    LOCK_FILE,
    lock_disagreements,
    locked_fingerprints,
    shipped_root,
    shipped_store,
)

STALE = "the shipped default model is stale: run `sonarmap train --ship` and commit configs/model"


def test_the_shipped_model_is_the_default_sections_model(tmp_path: Path) -> None:
    # An empty training directory: every recording comes from the lock, as on a new machine.
    config = load_config(all_stages(), None, [f"training.directory={tmp_path}"], extra_sections())
    training = config.training  # type: ignore[attr-defined]
    root = shipped_root(training.shipped_models)
    assert root is not None and (root / LOCK_FILE).is_file(), STALE
    sims = training_simulations(training)
    locked = locked_fingerprints(sims, training.shipped_models)
    assert locked is not None, f"{STALE} (a training recording's recipe is not in the lock)"
    key = plan_training([s.out for s in sims], config, model_cache(config), fingerprints=locked)
    lock = json.loads((root / LOCK_FILE).read_text())
    assert lock["train_key"] == key, STALE
    shipped = shipped_store(training.shipped_models)
    assert shipped is not None
    ref = shipped.get("train", key)
    assert ref is not None, STALE
    shipped.verify(ref)
    # Exactly one model ships: an old one left beside it is dead weight in every clone.
    assert [p.name for p in (root / "train").iterdir()] == [key]
    assert not list(tmp_path.iterdir()), "planning simulated or wrote something"


def test_a_recording_simulated_with_other_bytes_than_the_lock_is_named(tmp_path: Path) -> None:
    # A machine whose libraries round the simulation differently writes other bytes for a
    # recipe the lock names: it then plans another key and trains, and must say why.
    config = load_config(all_stages(), None, [f"training.directory={tmp_path}"], extra_sections())
    sims = training_simulations(config.training)  # type: ignore[attr-defined]
    root = tmp_path / "shipped"
    root.mkdir()
    lock = {
        "format": 1,
        "train_key": "0" * 64,
        "datasets": [{"file": s.out.name, "recipe": s.recipe(), "sha256": "a" * 64} for s in sims],
    }
    (root / LOCK_FILE).write_text(json.dumps(lock))
    same = {s.out: "a" * 64 for s in sims}
    assert lock_disagreements(sims, same, str(root)) == []
    other = {**same, sims[0].out: "b" * 64}
    (line,) = lock_disagreements(sims, other, str(root))
    assert line.startswith(f"{sims[0].out}: simulated here with other bytes")
    assert "bbbbbbbbbbbb… against aaaaaaaaaaaa…" in line
    # A recording not simulated yet, or a recipe the lock does not name, is not compared.
    assert lock_disagreements(sims, {}, str(root)) == []
    assert lock_disagreements(sims, other, str(tmp_path / "no-lock")) == []
