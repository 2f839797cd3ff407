"""One default model per machine: trained once, reused by every store, spacing and sweep.

A tiny training config (one short pier mission, 8 epochs) trains the model once into
the machine's model cache; everything after it must train nothing, which a patched
`train_classifier` counts.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import pytest
from typer.testing import CliRunner

import sonarmap.stages.classify.train
from sonarmap.pipeline.api import RunRequest, run_dataset
from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.config.load import load_config
from sonarmap.pipeline.engine.errors import ArtifactCorrupt
from sonarmap.pipeline.engine.share.push_pull import pull, push
from sonarmap.pipeline.engine.share.trust import TrustPolicy
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
from sonarmap.pipeline.graph import all_stages, extra_sections
from sonarmap.pipeline.training.config import TrainingDataConfig
from sonarmap.pipeline.training.datasets import ensure_simulation, scene_path
from sonarmap.pipeline.training.model import plan_training, training_datasets
from sonarmap.pipeline.training.model_cache import DEFAULT_MODEL_CACHE, resolve_default_model

CONFIG = """
training:
  sets:
    - {{scene: pier, seed: 7, goals: 3, duration_s: 70}}
  procedural: null
  directory: {training}
train:
  epochs: 8
classify:
  mc_passes: 8
"""


@dataclass(frozen=True)
class Machine:
    root: Path
    config: Path
    dataset: Path
    key: str

    @property
    def cache(self) -> ArtifactStore:
        return ArtifactStore(self.root / "training" / "store")


def _config(path: Path, *overrides: str) -> object:
    return load_config(all_stages(), path, overrides, extra_sections())


@pytest.fixture(scope="module")
def machine(tmp_path_factory: pytest.TempPathFactory) -> Machine:
    """A machine whose model cache holds the tiny default model (trained here, once)."""
    root = tmp_path_factory.mktemp("machine")
    config = root / "tiny.yaml"
    config.write_text(CONFIG.format(training=root / "training"))
    dataset = ensure_simulation(
        scene_path("tiny"), 2, root / "demo" / "tiny-seed2.mcap", duration_s=45
    )
    _, summary = run_dataset(
        RunRequest(dataset, config_path=config, store_dir=root / "a", until="classify")
    )
    assert summary["model"]["source"] == "trained"
    return Machine(root, config, dataset, summary["model"]["key"])


@pytest.fixture
def no_training(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Counts calls of the trainer; each one also fails the test's run loudly."""
    calls: list[int] = []

    def refuse(*_a: object, **_k: object) -> None:
        calls.append(1)
        raise AssertionError("trained although the machine has the model")

    monkeypatch.setattr(sonarmap.stages.classify.train, "train_classifier", refuse)
    return calls


def test_training_owns_its_keyframes_and_features_unless_following_the_run(
    machine: Machine,
) -> None:
    paths = training_datasets(_config(machine.config).training)  # type: ignore[attr-defined]

    def key(*overrides: str) -> str:
        return plan_training(paths, _config(machine.config, *overrides), machine.cache)

    assert key() == machine.key
    assert key("keyframes.spacing_m=4", "features.pfa=0.05") == machine.key
    assert key("training.keyframes.spacing_m=4") != machine.key
    assert key("training.features.pfa=0.05") != machine.key
    follow = key("training.follow_run=true", "keyframes.spacing_m=4")
    assert follow == key("training.keyframes.spacing_m=4")
    assert key("training.follow_run=true") == machine.key  # run defaults = training defaults
    assert Path(TrainingDataConfig().directory) / "store" == DEFAULT_MODEL_CACHE


def test_demo_on_a_new_store_trains_nothing_and_its_headline_is_the_aligned_error(
    machine: Machine, no_training: list[int]
) -> None:
    args = [
        "demo", "--scene", "tiny", "--seed", "2", "--duration-s", "45",
        "--out", str(machine.root / "demo"), "--store", str(machine.root / "b"),
        "--config", str(machine.config),
    ]  # fmt: skip
    res = CliRunner().invoke(app, args, env={"COLUMNS": "250"})
    assert res.exit_code == 0, res.output
    assert no_training == []
    assert f"classifier: train/{machine.key[:12]} (copied from the model cache" in res.output
    coverage = res.output[res.output.index("Coverage (") :]
    header = next(line for line in coverage.splitlines() if "median error m" in line)
    labels = [c.strip() for c in header.strip("┃│ ").replace("┃", "│").split("│")]
    assert labels[:4] == ["map", "voxels", "accurate voxels", "completeness"]
    assert labels[4].startswith("median error m, SE(2)-aligned (rotation ")
    assert labels[4].endswith("°)") and labels[5] == "raw median error m"
    report = (machine.root / "demo" / "report" / "report.md").read_text()
    first = report.split("## Coverage (paper Table I)")[1].strip().splitlines()[0]
    assert "| median error m, SE(2)-aligned (rotation " in first
    assert first.index("SE(2)-aligned") < first.index("raw median error m")
    store = ArtifactStore(machine.root / "b")
    train = store.get("train", machine.key)
    assert train is not None
    store.verify(train)
    assert f"train/{machine.key}" not in store.gc(dry_run=True)["removed"]  # a run relies on it
    # The training datasets' keyframes stay in the cache: the new store built none of them.
    keys = lambda s: {r.key for r in s.iter_artifacts() if r.stage == "keyframes"}  # noqa: E731
    assert keys(machine.cache) and not keys(machine.cache) & keys(store)


def test_sweep_over_keyframe_spacing_trains_nothing(
    machine: Machine, no_training: list[int]
) -> None:
    out = machine.root / "sweep"
    args = [
        "sweep", str(machine.dataset), "--set", "keyframes.spacing_m=2,4",
        "--config", str(machine.config), "--store", str(machine.root / "b"),
        "--out", str(out), "--json",
    ]  # fmt: skip
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert [r["status"] for r in doc["runs"]] == ["ok", "ok"], doc["runs"]
    assert no_training == []
    assert {r["summary"]["model"]["key"] for r in doc["runs"]} == {machine.key}
    header = (out / "table.md").read_text().splitlines()[0]
    assert header.index("median_error_standard_m (SE(2)-aligned)") < header.index(
        "| median_error_standard_m |"
    )


def test_a_pulled_model_is_used_and_published_to_a_machine_without_it(
    machine: Machine, no_training: list[int]
) -> None:
    """Pushed from a store whose model came from the cache (its training data with it),
    pulled into a store on a machine whose cache is empty: used, and then cached."""
    remote = machine.root / "remote"
    pushed = push(
        ArtifactStore(machine.root / "a"),
        str(remote),
        ["train"],
        fallbacks=[machine.cache],
        create=True,
    )
    assert pushed[-1] == f"train/{machine.key}" and len(pushed) == 3  # keyframes, features
    other = machine.root / "other-machine"
    shutil.copytree(machine.root / "training", other, ignore=shutil.ignore_patterns("store"))
    config = _config(machine.config, f"training.directory={other}")
    store = ArtifactStore(machine.root / "c")
    # A model from a remote is accepted only when pinned (pipeline.engine.trust).
    model = ArtifactStore(machine.root / "a").get("train", machine.key)
    assert model is not None
    trusted = TrustPolicy.build([TrustPolicy.model_sha(model.manifest)])
    assert {r.stage for r in pull(store, str(remote), ["train"], policy=trusted)} == {
        "keyframes",
        "features",
        "train",
    }
    chosen = resolve_default_model(store, config)
    assert (chosen.source, chosen.ref.key) == ("store", machine.key)
    assert ArtifactStore(other / "store").get("train", machine.key) is not None
    assert no_training == []


def test_a_tampered_cached_model_is_refused_and_the_store_keeps_nothing(
    machine: Machine, no_training: list[int]
) -> None:
    other = machine.root / "tampered"
    shutil.copytree(machine.root / "training", other)
    blob = next((other / "store" / "train").glob("*/model.pt"))
    raw = blob.read_bytes()
    blob.write_bytes(bytes([raw[0] ^ 1]) + raw[1:])
    store = ArtifactStore(machine.root / "d")
    config = _config(machine.config, f"training.directory={other}")
    with pytest.raises(ArtifactCorrupt, match=r"model\.pt.*sha256.*remove"):
        resolve_default_model(store, config)
    assert store.get("train", machine.key) is None and no_training == []


def _fresh_machine(machine: Machine, name: str, shipped: Path) -> object:
    """A config for a machine with no training recordings and an empty model cache."""
    return _config(
        machine.config,
        f"training.directory={machine.root / name}",
        f"training.shipped_models={shipped}",
    )


def _ship_tiny(machine: Machine, shipped: Path) -> None:
    from sonarmap.pipeline.engine.run.session import dataset_spec
    from sonarmap.pipeline.graph import default_graph
    from sonarmap.pipeline.training.model import training_simulations
    from sonarmap.pipeline.training.shipped import ship

    training = _config(machine.config).training  # type: ignore[attr-defined]
    sims = training_simulations(training)
    fingerprints = [dataset_spec(s.out, machine.cache, default_graph()).fingerprint for s in sims]
    ref = machine.cache.get("train", machine.key)
    assert ref is not None
    ship(ref, sims, fingerprints, shipped)


def test_a_fresh_machine_takes_the_shipped_model_without_simulating_or_training(
    machine: Machine, no_training: list[int]
) -> None:
    from sonarmap.pipeline.training.model_cache import planned_default_model

    shipped = machine.root / "shipped"
    _ship_tiny(machine, shipped)
    config = _fresh_machine(machine, "fresh", shipped)
    store = ArtifactStore(machine.root / "e")
    assert planned_default_model(store, config) == (machine.key, True)
    chosen = resolve_default_model(store, config)
    assert (chosen.source, chosen.ref.key) == ("shipped", machine.key)
    store.verify(chosen.ref)
    # Nothing simulated: the training directory holds only the model cache.
    assert [p.name for p in (machine.root / "fresh").iterdir()] == ["store"]
    assert ArtifactStore(machine.root / "fresh" / "store").get("train", machine.key)
    assert no_training == []
    # A lock whose recipe is not this config's plans nothing: the simulation is needed.
    stale = _config(
        machine.config,
        f"training.directory={machine.root / 'fresh-other'}",
        f"training.shipped_models={shipped}",
        "training.sets=[{scene: pier, seed: 8, goals: 3, duration_s: 70}]",
    )
    assert planned_default_model(store, stale) == ("", False)


def test_a_tampered_shipped_model_is_refused(machine: Machine, no_training: list[int]) -> None:
    shipped = machine.root / "shipped-tampered"
    _ship_tiny(machine, shipped)
    blob = next((shipped / "train").glob("*/model.pt"))
    raw = blob.read_bytes()
    blob.write_bytes(raw[:-1] + bytes([raw[-1] ^ 1]))
    store = ArtifactStore(machine.root / "f")
    with pytest.raises(ArtifactCorrupt, match=r"shipped model: .*model\.pt.*sha256"):
        resolve_default_model(store, _fresh_machine(machine, "fresh-tampered", shipped))
    assert store.get("train", machine.key) is None and no_training == []


def test_train_ship_writes_the_model_and_the_lock_a_fresh_machine_plans_from(
    machine: Machine, no_training: list[int]
) -> None:
    from sonarmap.pipeline.training.model_cache import planned_default_model

    shipped = machine.root / "shipped-cli"
    args = [
        "train", "--ship", "--config", str(machine.config),
        "--set", f"training.shipped_models={shipped}",
        "--store", str(machine.root / "g"), "--json",
    ]  # fmt: skip
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["key"] == machine.key
    lock = json.loads((shipped / "lock.json").read_text())
    assert lock["train_key"] == machine.key and len(lock["datasets"]) == 1
    fresh = _fresh_machine(machine, "fresh-cli", shipped)
    assert planned_default_model(ArtifactStore(machine.root / "h"), fresh) == (machine.key, True)
    assert no_training == []
    bad = CliRunner().invoke(app, ["train", "--ship", str(machine.dataset)])
    assert bad.exit_code == 2 and "give no datasets" in bad.output
