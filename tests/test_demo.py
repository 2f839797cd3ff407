"""The demo path end to end on a small scene: simulate, train, every stage, report, cache."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.run import workers
from sonarmap.pipeline.engine.run.compute import ComputeJob

ROOT = Path(__file__).resolve().parent.parent

HEAVY = (
    "torch", "open3d", "scipy", "matplotlib", "sklearn", "gtsam", "kiss_icp", "mcap",
    "mcap_ros2", "numpy", "pyarrow",
)  # fmt: skip
"""Libraries a fully cached run never needs: only a stage that computes, or a reader that
decodes a recording, loads them (docs/decisions/020-cached-run-imports.md)."""

PENDING: dict[str, str] = {}
"""Heavy libraries a cached run still loads until the named module is split like the
other stages (config and declaration apart from the computation); each entry must still
be needed, so it goes when its import does."""

CONFIG = """
training:
  sets:
    - {scene: pier, seed: 7, goals: 3, duration_s: 70}
  procedural: null
  directory: {training_dir}
train:
  epochs: 8
classify:
  mc_passes: 8
"""


def test_demo_on_a_small_scene_then_fully_cached(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Every job the runner weighs sending to a worker process can travel there: one that
    # could not (a closure anywhere in it) would wait for this process, and two workers
    # would quietly run one stage at a time.
    weighed: list[tuple[str, bool]] = []
    picklable = workers._picklable

    def spy(job: ComputeJob) -> bool:
        weighed.append((job.item.stage.name, picklable(job)))
        return weighed[-1][1]

    monkeypatch.setattr(workers, "_picklable", spy)
    config = tmp_path / "demo.yaml"
    config.write_text(CONFIG.replace("{training_dir}", str(tmp_path / "training")))
    args = [
        "demo", "--scene", "tiny", "--seed", "2", "--duration-s", "45",
        "--out", str(tmp_path / "demo"), "--store", str(tmp_path / "store"),
        "--config", str(config), "--json", "--workers", "2",
    ]  # fmt: skip
    runner = CliRunner()
    first = runner.invoke(app, args)
    assert first.exit_code == 0, first.output
    doc = json.loads(first.stdout)
    assert weighed and all(ok for _, ok in weighed), weighed
    stages = [s["stage"] for s in doc["stages"]]
    assert stages == [
        "keyframes",
        "features",
        "fuse",
        "classify",
        "slam",
        "infer",
        "submaps",
        "voxelize",
        "evaluate",
        "figures",
        "map_figures",
    ]
    summary = doc["summary"]
    # The counts in summary.json match an independent count from map.parquet.
    voxelize = next(s for s in doc["stages"] if s["stage"] == "voxelize")
    world = pq.read_table(Path(voxelize["path"]) / "map.parquet")
    xyz = np.stack([world.column(c).to_numpy() for c in ("x_m", "y_m", "z_m")], axis=1)
    fused = np.array(world.column("source").to_pylist()) == "fused"
    for name, rows in (("standard", xyz[fused]), ("semantic", xyz)):
        cells = {tuple(v) for v in np.floor(rows / 0.1).astype(np.int64)}
        assert summary["voxels"][name] == len(cells)
    assert summary["voxels"]["standard"] > 0
    metrics = summary["metrics"]
    assert metrics["errors"]["standard"]["n"] > 0
    assert metrics["errors"]["standard"]["median_m"] < 0.3
    report = Path(summary["report"])
    assert report.is_file() and report.stat().st_size > 200
    assert "## Stages" in report.read_text() and "| evaluate |" in report.read_text()
    # The classifier's shares of sure objects count the objects table's own acceptances,
    # and the report states them.
    classify = Path(next(s["path"] for s in doc["stages"] if s["stage"] == "classify"))
    acceptance = json.loads((classify / "acceptance.json").read_text())
    objects = pq.read_table(classify / "objects.parquet")
    accepted = np.count_nonzero(
        objects.column("class_name").to_numpy(zero_copy_only=False) != "unknown"
    )
    # Sure (pooled p over the threshold) and accepted differ by what min_views held back.
    sure = np.count_nonzero(objects.column("probability").to_numpy() > acceptance["threshold"])
    assert acceptance["objects"] == objects.num_rows > 0
    assert acceptance["pooled_sure_fraction"] == round(sure / objects.num_rows, 4)
    assert acceptance["unconfirmed"] == sure - accepted
    assert 0.0 <= acceptance["sure_fraction"] <= 1.0
    assert "## Classifier" in report.read_text()
    pngs = {
        p.name for p in report.parent.iterdir() if p.suffix == ".png" and p.stat().st_size > 1000
    }
    figures = {"overlay.png", "trajectory.png", "errors.png", "map_topdown.png", "side_view.png"}
    assert pngs == figures and all(f"]({name})" in report.read_text() for name in figures)
    # Everything cached: nothing is computed the second time.
    t0 = time.perf_counter()
    second = runner.invoke(app, args)
    assert second.exit_code == 0, second.output
    assert {s["status"] for s in json.loads(second.stdout)["stages"]} == {"hit"}
    assert time.perf_counter() - t0 < 30
    # The same cached demo as a fresh process, as a user runs it: nothing heavy loads.
    plain = [a for a in args if a != "--json"]
    assert _heavy_modules_after(plain) == sorted(PENDING)
    # One stage at a time, every stage recomputed: the same keys and the same bytes as
    # the run with two workers.
    files = {s["stage"]: _files(Path(s["path"])) for s in doc["stages"]}
    forced = [arg for stage in stages for arg in ("--force", stage)]
    serial = runner.invoke(
        app,
        ["run", doc["dataset"], "--store", str(tmp_path / "store"), "--config", str(config),
         "--json", "--workers", "1", *forced],
    )  # fmt: skip
    assert serial.exit_code == 0, serial.output
    again = json.loads(serial.stdout)["stages"]
    assert {s["status"] for s in again} == {"computed"}
    assert [(s["stage"], s["key"]) for s in again] == [
        (s["stage"], s["key"]) for s in doc["stages"]
    ]
    assert {s["stage"]: _files(Path(s["path"])) for s in again} == files


def _files(artifact: Path) -> dict[str, str]:
    """An artifact's files and their sha256s, as its manifest lists them."""
    manifest = json.loads((artifact / "manifest.json").read_text())
    return {name: info["sha256"] for name, info in manifest["files"].items()}


def _heavy_modules_after(args: list[str]) -> list[str]:
    """The `HEAVY` libraries loaded by `sonarmap ARGS` run in a fresh interpreter."""
    script = (
        "import json, runpy, sys\n"
        "sys.argv = ['sonarmap', *sys.argv[1:]]\n"
        "try:\n"
        "    runpy.run_module('pipeline', run_name='__main__', alter_sys=True)\n"
        "except SystemExit as end:\n"
        "    assert not end.code, end.code\n"
        f"print(json.dumps(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r}))))\n"
    )
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    proc = subprocess.run(
        [sys.executable, "-c", script, *args], capture_output=True, text=True, env=env, cwd=ROOT
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])
