"""A run pointed at a trained model: `--set classify.model=PATH` or `train/<key>` (issue 38.3)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = next((ROOT / "configs" / "model" / "train").iterdir())


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from sonarmap.pipeline.formats.simulation import write_simulation
    from sonarmap.sim.config import SimConfig
    from sonarmap.sim.dataset import simulate
    from sonarmap.sim.scene import load_scene

    scene = ROOT / "configs" / "scenes" / "tiny.yaml"
    base = SimConfig()
    mission = base.mission.model_copy(update={"n_goals": 2, "duration_s": 20.0})
    run = simulate(load_scene(scene), base.model_copy(update={"mission": mission}), 3)
    path = tmp_path_factory.mktemp("sim") / "tiny.mcap"
    write_simulation(run, path, scene_yaml=scene.read_text())
    return path


def _run(recording: Path, store: Path, *settings: str) -> tuple[int, str, dict]:
    args = ["run", str(recording), "--store", str(store), "--until", "classify", "--json"]
    for s in settings:
        args += ["--set", s]
    result = CliRunner().invoke(app, args)
    doc = json.loads(result.stdout) if result.exit_code == 0 else {}
    return result.exit_code, result.output, doc


def _classify_key(doc: dict) -> str:
    return next(s["key"] for s in doc["stages"] if s["stage"] == "classify")


def test_a_model_folder_and_its_key_give_the_run_the_same_classify_key(
    recording: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "model"
    shutil.copytree(SHIPPED, folder)  # what `train -o DIR` writes: files and manifest
    code, output, by_path = _run(recording, tmp_path / "a", f"classify.model={folder}")
    assert code == 0, output
    assert by_path["summary"]["model"]["source"] == "given"
    code, output, by_key = _run(
        recording, tmp_path / "a", f"classify.model=train/{SHIPPED.name[:12]}"
    )
    assert code == 0, output
    code, output, default = _run(recording, tmp_path / "b")
    assert code == 0, output
    assert _classify_key(by_path) == _classify_key(by_key) == _classify_key(default)


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ("classify.model={tmp}/nothing", "no manifest.json"),
        ("classify.model=train/ffffeeee", "no trained model train/ffffeeee"),
        ("classify.model={tmp}/tampered", "model.pt"),
        ("classify.model={tmp}/unvalidated", "without a validation split"),
    ],
)
def test_a_model_that_is_not_there_altered_or_unvalidated_is_refused_in_one_line(
    recording: Path, tmp_path: Path, setting: str, message: str
) -> None:
    (tmp_path / "nothing").mkdir()
    tampered = tmp_path / "tampered"
    shutil.copytree(SHIPPED, tampered)
    with (tampered / "model.pt").open("r+b") as f:
        f.seek(100)
        f.write(b"\x00\x01\x02")
    unvalidated = tmp_path / "unvalidated"
    shutil.copytree(SHIPPED, unvalidated)
    metrics = json.loads((unvalidated / "metrics.json").read_text())
    (unvalidated / "metrics.json").write_text(json.dumps({**metrics, "n": 0}))
    code, output, _ = _run(recording, tmp_path / "store", setting.format(tmp=tmp_path))
    assert code == 2 and message in output
    assert len([line for line in output.splitlines() if line.startswith("error:")]) == 1
    assert "Traceback" not in output
    assert not (tmp_path / "store" / "classify").exists()
