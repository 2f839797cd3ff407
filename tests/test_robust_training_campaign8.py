"""Campaign 8: training and classes on the user's own data, and using models (each test
failed before its fix)."""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
from pathlib import Path
from typing import Any

import pytest
from pydantic import ValidationError
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.config.load import load_config
from sonarmap.pipeline.engine.errors import ArtifactCorrupt
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
from sonarmap.pipeline.graph import all_stages, extra_sections
from sonarmap.pipeline.training.model_cache import model_cache, resolve_default_model
from sonarmap.pipeline.training.model_choice import locate_given_model
from sonarmap.pipeline.training.shipped import shipped_store
from sonarmap.schemas.classes import ClassEntry, ClassTable
from sonarmap.stages.classify.train import UnknownLabel
from sonarmap.stages.evaluate.config import EvaluateConfig
from tests.fixtures.recordings import small_recording


def _config(*overrides: str) -> Any:
    return load_config(all_stages(), None, overrides, extra_sections())


def _impostor(tmp_path: Path) -> Path:
    """The shipped model's folder with another model.pt, its manifest re-hashed: what a
    shared folder claiming the shipped recipe looks like."""
    shipped = shipped_store(_config().training.shipped_models)
    assert shipped is not None
    (ref,) = [r for r in shipped.iter_artifacts() if r.stage == "train"]
    folder = tmp_path / "impostor"
    shutil.copytree(ref.path, folder)
    model = folder / "model.pt"
    model.write_bytes(model.read_bytes() + b"\0")  # any other bytes
    manifest = json.loads((folder / "manifest.json").read_text())
    data = model.read_bytes()
    manifest["files"]["model.pt"] = {"sha256": hashlib.sha256(data).hexdigest(), "size": len(data)}
    (folder / "manifest.json").write_text(json.dumps(manifest))
    return folder


def test_a_folder_claiming_the_shipped_recipe_never_takes_its_place(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """`classify.model=DIR` copied it into the store under the shipped key; every later
    default run then said "train/9ee607fa (found in the store)" and used its weights."""
    folder = _impostor(tmp_path)
    store = ArtifactStore(tmp_path / "store")
    with pytest.raises(ArtifactCorrupt, match=r"holds another model\.pt"):
        locate_given_model(str(folder), store, _config(), allow_unvalidated=True)
    assert not (store.root / "train").exists()
    # ... and one already there (a substitute pinned and pulled: allowed, its classify keys
    # are its own) is named with its bytes, since the run's line names the shipped key
    shutil.copytree(folder, store.root / "train" / json.loads(
        (folder / "manifest.json").read_text())["key"])  # fmt: skip
    with caplog.at_level("WARNING"):
        resolve_default_model(store, _config())
    assert "holds a model.pt other than the shipped model's" in caplog.text
    # ... and it stays in its store: copied into the model cache under the shipped key, it
    # made every other store's default run refuse the shipped model
    cache = model_cache(_config())
    held = cache.get("train", json.loads((folder / "manifest.json").read_text())["key"])
    assert (
        held is None or (held.path / "model.pt").read_bytes() != (folder / "model.pt").read_bytes()
    )


def test_status_plans_with_the_model_a_run_would_use(tmp_path: Path) -> None:
    """`status` ignored `classify.model`: it planned the shipped model's keys, and said
    nothing of a folder that is not there (`run` refuses it, exit 2)."""
    rec = small_recording(tmp_path / "rec.mcap", duration_s=8.0)
    res = CliRunner().invoke(app, ["status", str(rec), "--store", str(tmp_path / "s"),
                                   "--set", "classify.model=/nonexistent/dir"])  # fmt: skip
    assert res.exit_code == 2, res.output
    assert "classify.model: /nonexistent/dir: no manifest.json" in res.stderr


def test_labels_of_a_class_the_table_left_out_are_bad_input_naming_the_dataset() -> None:
    err = UnknownLabel(2, 0)
    assert isinstance(err, ValueError) and err.dataset == 0
    assert "class id 2" in str(err) and "`classes`" in str(err)


@pytest.mark.parametrize(
    ("field", "value"), [("id", True), ("inferred", 1), ("inferred", "true"), ("completeness", 0)]
)
def test_the_class_table_is_as_strict_as_every_other_section(field: str, value: Any) -> None:
    """`id: true` was read as 1 and `inferred: "true"` as true (other sections refuse both)."""
    entry = {"name": "mooring_block", "id": 9, field: value}
    with pytest.raises(ValidationError):
        ClassEntry.model_validate(entry)


def test_the_table_s_completeness_flag_takes_effect() -> None:
    """`evaluate.completeness_classes` defaulted to the default table's pilings whatever the
    table said: `completeness: true` on a class of one's own did nothing."""
    table = ClassTable.model_validate(
        {"table": [{"name": "none", "id": 0, "frame_kind": "none"},
                   {"name": "quay_wall", "id": 1, "frame_kind": "beam", "completeness": True}]}
    )  # fmt: skip
    assert EvaluateConfig().completeness(table) == ("quay_wall",)
    assert EvaluateConfig().completeness() == ("cylindrical_piling", "rectangular_piling")
    given = EvaluateConfig(completeness_classes=["cylindrical_piling"])
    assert given.completeness(table) == ("cylindrical_piling",)


def test_one_recording_given_twice_to_train_is_refused(tmp_path: Path) -> None:
    """Its objects counted twice (which can lift a class over train.min_class_samples)."""
    rec = tmp_path / "a.mcap"
    rec.write_bytes(b"not read: refused before")
    link = tmp_path / "c.mcap"
    link.symlink_to(rec)
    runner = CliRunner()
    for args, needle in (([rec, link], "the same recording as"), ([rec, rec], "given twice")):
        res = runner.invoke(app, ["train", *map(str, args), "-o", str(tmp_path / "m")])
        assert res.exit_code == 2, res.output
        assert needle in res.stderr


@pytest.mark.parametrize("damage", ["altered", "missing"])
def test_a_bad_model_folder_is_named_not_the_stores_temporary_copy(
    tmp_path: Path, damage: str
) -> None:
    """The error named `store/.tmp/train-…` (campaign 8 #10), or was a bare ENOENT."""
    from sonarmap.pipeline.training.model_cache import copy_verified

    src = ArtifactStore(tmp_path / "src")

    def build(tmp: Path) -> dict[str, Any]:
        (tmp / "model.pt").write_bytes(b"weights")
        (tmp / "settings.json").write_text("{}")
        return {}

    ref = src.commit("train", "ab" * 32, build, {})
    if damage == "altered":
        (ref.path / "model.pt").write_bytes(b"WEIGHTS")
    else:
        (ref.path / "settings.json").unlink()
    with pytest.raises(ArtifactCorrupt) as err:
        copy_verified(ref, ArtifactStore(tmp_path / "dest"))
    assert str(ref.path) in str(err.value) and ".tmp" not in str(err.value), err.value
    assert ("model.pt" if damage == "altered" else "settings.json") in str(err.value)


def test_an_error_in_classes_add_names_add_not_the_table(tmp_path: Path) -> None:
    """It said `classes.table[7].colour`, a path the user never wrote (campaign 8 #10)."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "classes:\n  add:\n    - {name: mooring_block, id: 7, frame_kind: object, colour: 12}\n"
    )
    res = CliRunner().invoke(app, ["config", "check", str(bad)])
    assert res.exit_code == 2
    assert "classes.add[0].colour" in res.output and "table[7]" not in res.output


def test_a_class_the_table_infers_but_the_model_lacks_is_warned_of(tmp_path: Path) -> None:
    """An added class whose labels never reached the model: `run` was silent (#7)."""
    rec = small_recording(tmp_path / "rec.mcap", duration_s=20.0)
    config = tmp_path / "mooring.yaml"
    config.write_text(
        "classes:\n  add:\n    - {name: mooring_block, id: 7, frame_kind: object,"
        " inferred: true, colour: '#8c564b'}\n"
    )
    # The shipped model named: the added class moves the default model's key (a retrain).
    (shipped,) = (Path(__file__).resolve().parents[1] / "configs" / "model" / "train").iterdir()
    args = ["run", str(rec), "--store", str(tmp_path / "s"), "--until", "classify"]
    args += ["--set", f"classify.model={shipped}"]
    res = CliRunner().invoke(app, [*args, "--config", str(config), "--json"])
    assert res.exit_code == 0, res.output
    warned = [w for s in json.loads(res.stdout)["stages"] for w in s.get("warnings", [])]
    assert any("model has no class mooring_block" in w for w in warned), warned
    plain = CliRunner().invoke(app, [*args, "--json"])
    assert plain.exit_code == 0, plain.output
    assert not any(
        "model has no class" in w
        for s in json.loads(plain.stdout)["stages"]
        for w in s.get("warnings", [])
    )


def test_a_cached_model_says_the_training_s_warnings_again(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A second `train` of the same recordings took the model from the store and said
    nothing of the classes it does not know (campaign 8 #9)."""
    from sonarmap.pipeline.training.datasets import ensure_simulation

    root = Path(__file__).resolve().parents[1]
    rec = ensure_simulation(
        root / "configs/scenes/marina.yaml", 1, tmp_path / "m.mcap", goals=1, duration_s=20.0
    )
    args = ["train", str(rec), "--out", str(tmp_path / "model"), "--store", str(tmp_path / "s"),
            "--set", "train.epochs=1", "--set", "train.mc_passes=2",
            "--set", "train.min_class_samples=2"]  # fmt: skip
    said = []
    for _ in range(2):
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            res = CliRunner().invoke(app, args)
        assert res.exit_code == 0, res.output
        said.append([r.getMessage() for r in caplog.records if r.levelno == logging.WARNING])
    assert any("no labelled training object" in w for w in said[0]), said[0]
    assert said[1] == said[0]
    metrics = json.loads((tmp_path / "model" / "metrics.json").read_text())
    assert metrics["warnings"] == said[0]
