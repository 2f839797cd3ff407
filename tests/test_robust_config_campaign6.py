"""Campaign 6: configuration, sweeps and the study as a user meets them (each test failed
before its fix)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pydantic import ValidationError
from test_sweep_faults import _sweep
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.training.cache_dir import CACHE_ENV, cache_root
from sonarmap.stages.base import StageSettingsError
from sonarmap.stages.evaluate.config import EvaluateConfig
from sonarmap.stages.evaluate.stage import MAX_SURFACE_SAMPLES, surface_metrics
from sonarmap.stages.features.config import FeaturesConfig
from sonarmap.stages.kernels.mesh_metrics import sampled_area_m2, surface_samples
from sonarmap.stages.kernels.ply import Mesh
from sonarmap.stages.slam.config import SlamConfig


def _cli(*args: str) -> Any:
    return CliRunner().invoke(app, list(args))


def _one_error_line(res: Any, *needles: str) -> str:
    assert res.exit_code == 2, res.output
    lines = res.stderr.strip().splitlines()
    assert lines and lines[-1].startswith("error: "), res.stderr
    assert "Traceback" not in res.output
    for needle in needles:
        assert needle in lines[-1], lines[-1]
    return lines[-1]


def test_a_sweep_reads_its_config_once_and_keeps_it_with_the_results(
    toy_env: list[Path], tmp_path: Path
) -> None:
    """Each point read the file again: edited during a sweep, it changed the later points."""
    config = tmp_path / "protocol.yaml"
    config.write_text("summary:\n  label: first\n")
    out = tmp_path / "o"
    res = _sweep(str(toy_env[0]), "-c", str(config), "--set", "double.factor=5,11,7",
                 "--store", str(tmp_path / "s"), "--out", str(out))  # fmt: skip
    assert res.returncode == 0, res.stderr
    kept = out / "config.yaml"
    assert kept.read_bytes() == config.read_bytes()
    runs = json.loads((out / "sweep.json").read_text())["runs"]
    assert {r["config_path"] for r in runs} == {str(kept.resolve())}
    # the table in the order the values were given (sorted as text, 11 came first)
    rows = [ln for ln in (out / "table.md").read_text().splitlines()[2:] if ln]
    assert [ln.split("|")[1].strip() for ln in rows] == [
        "double.factor=5", "double.factor=11", "double.factor=7"
    ]  # fmt: skip


def test_sweeps_that_differ_only_in_fix_get_their_own_results(
    toy_env: list[Path], tmp_path: Path
) -> None:
    """Both wrote data/sweeps/<same id>: the second replaced the first without a word."""
    folders = []
    for label in ("a", "b"):
        res = subprocess.run(
            [sys.executable, "-m", "sonarmap.pipeline", "sweep", str(toy_env[0]), "--set",
             "double.factor=2,3", "--fix", f"summary.label={label}", "--store",
             str(tmp_path / "s")],
            capture_output=True, text=True, timeout=120, env=os.environ.copy(), cwd=tmp_path,
        )  # fmt: skip
        assert res.returncode == 0, res.stderr
        folders.append(res.stdout.strip().splitlines()[-1])
    assert folders[0].startswith("results: ") and folders[0] != folders[1]


def test_a_figure_less_sweep_takes_a_config_with_a_figures_section(tmp_path: Path) -> None:
    """`sweep --no-figures` refused `figures.*` (a dumped config) as an unknown key."""
    missing = tmp_path / "missing.mcap"
    res = _cli("sweep", str(missing), "--no-figures", "--fix", "figures.overlay=false",
               "--store", str(tmp_path / "s"), "--out", str(tmp_path / "o"))  # fmt: skip
    _one_error_line(res, "missing.mcap", "no such file")  # past the config check


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--set", "keyframes.horizontal_topic=/a\udcff"], "not UTF-8 text (byte 2 is 0xff)"),
        (["--set", "keyframes.spacing_m=3", "--set", "keyframes.spacing_m=4"], "given twice"),
        (["--set", "keyframes.spacing_m=3", "--set", "keyframes={rotation_deg: 10}"], "then its"),
        (["--set", "fuse.patch_size_px=4"], "patch_size_px must be odd"),
        (["--set", "keyframes.horizontal_sonar=nonexistent_preset"], "neither a preset"),
    ],
)
def test_config_values_a_run_cannot_take_are_refused_with_one_line(
    args: list[str], needle: str, tmp_path: Path
) -> None:
    """Each was exit 1 (a traceback's last line), silently dropped, or refused only when
    its stage ran."""
    cfg = tmp_path / "c.yaml"
    dumped = _cli("config", "dump", *args)
    if "neither a preset" in needle:  # a reference: `config check` reads it as a run would
        assert dumped.exit_code == 0, dumped.output
        cfg.write_text(dumped.stdout)
        _one_error_line(_cli("config", "check", str(cfg)), "keyframes.horizontal_sonar", needle)
    else:
        _one_error_line(dumped, needle)


def test_settings_a_stage_cannot_compute_in_bounded_memory_are_refused() -> None:
    with pytest.raises(ValidationError, match="at most the training cells"):
        FeaturesConfig(method="os", os_rank=21)
    FeaturesConfig(method="os", os_rank=20)
    with pytest.raises(ValidationError, match="less than or equal to 5"):
        SlamConfig(point_noise_m=30.0)  # 21 GB of overlap neighbourhoods
    with pytest.raises(ValidationError, match="at most 40 x"):
        SlamConfig(grid_resolution_m=0.05, point_noise_m=2.5)
    square = Mesh(
        vertices=np.array([[0, 0, 0], [10, 0, 0], [0, 0, 10], [10, 0, 10]], float),
        triangles=np.array([[0, 1, 2], [1, 3, 2]]),
        vertex_properties={"class_id": np.ones(4, np.int64)},
    )  # a 100 m2 wall
    assert sampled_area_m2(square, np.array([1])) == pytest.approx(100.0)
    assert len(surface_samples(square, np.array([1]), 100.0, 0)) == 10_000
    config = EvaluateConfig(
        completeness_classes=["cylindrical_piling"],
        surface_samples_per_m2=1.01 * MAX_SURFACE_SAMPLES / 100,
    )  # 24 GB and the OOM killer at 1e6 per m2 on the marina
    with pytest.raises(StageSettingsError, match=r"evaluate\.surface_samples_per_m2"):
        surface_metrics(None, None, square, np.eye(4), config)  # type: ignore[arg-type]


def test_a_pose_graph_gtsam_cannot_solve_is_a_settings_error(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """GTSAM's multi-line RuntimeError was exit 1 ("stage slam failed")."""
    from sonarmap.stages.slam import stage as slam_stage
    from tests.fixtures import simulated_slam_inputs

    def indeterminate(*_a: Any, **_k: Any) -> None:
        raise RuntimeError("\nIndeterminate linear system detected while working near variable")

    inputs = simulated_slam_inputs("tiny", n_goals=1)
    monkeypatch.setattr(slam_stage, "run_slam", indeterminate)
    with pytest.raises(StageSettingsError, match="slam sigmas"):
        slam_stage.STAGE.run(SlamConfig(), inputs)


def test_the_study_refuses_its_spacings_before_simulating(tmp_path: Path) -> None:
    """`--spacings 2,2` was refused after every trial was simulated, naming a --set."""
    out = tmp_path / "study"
    for args, needle in (
        (["--spacings", "2,2"], "--spacings '2,2': value 2 given twice"),
        (["--spacings", ","], "--spacings ',': no value to sweep"),
        (["--fix", "slam.mode=dead_reckoning"], "true poses"),
    ):
        res = _cli("study", "--trials", "1", "--goals", "1", "--out", str(out),
                   "--store", str(tmp_path / "s"), *args)  # fmt: skip
        _one_error_line(res, needle)
        assert not list(out.glob("*.mcap"))


@pytest.mark.parametrize("order", [["--json", "--bogus"], ["--bogus", "--json"]])
def test_json_gets_its_error_document_wherever_it_stands(order: list[str]) -> None:
    res = _cli("status", "x.mcap", *order)
    assert res.exit_code == 2
    assert json.loads(res.stdout)["exit_code"] == 2


def test_a_cache_dir_that_is_a_file_is_named(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    afile = tmp_path / "afile"
    afile.write_text("x")
    monkeypatch.setenv(CACHE_ENV, str(afile))
    with pytest.raises(ConfigError, match="a file, not a folder"):
        cache_root()


def test_a_force_after_until_is_refused_not_ignored(toy_cli: Path, tmp_path: Path) -> None:
    """Campaign 6 #19: `--until double --force summary` ran without recomputing anything."""
    store = str(tmp_path / "s")
    res = _cli("run", str(toy_cli), "--store", store, "--until", "double", "--force", "summary")
    _one_error_line(res, "--force summary", "--until double")
    assert not (tmp_path / "s" / "double").exists()  # refused before any work
    assert _cli("run", str(toy_cli), "--store", store, "--until", "summary",
                "--force", "double", "-q").exit_code == 0  # fmt: skip


def test_an_infinite_mission_duration_is_refused(tmp_path: Path) -> None:
    """Campaign 6 #19: `simulate --duration-s inf` simulated the whole mission, saying nothing."""
    res = _cli("simulate", "--duration-s", "inf", "--goals", "1", "-o", str(tmp_path / "m.mcap"))
    _one_error_line(res, "--duration-s inf")
    assert not (tmp_path / "m.mcap").exists()


def test_a_reordered_set_of_classes_keys_the_same_voxel_map() -> None:
    """Campaign 6 #16: `voxelize.evidence_classes` is a set; its order changed the key."""
    from sonarmap.stages.voxelize.config import VoxelizeConfig

    one = VoxelizeConfig(evidence_classes=("truss", "seawall"))
    other = VoxelizeConfig(evidence_classes=("seawall", "truss", "seawall"))
    assert one.model_dump() == other.model_dump()
    assert one.evidence_classes == ("seawall", "truss")
    assert (
        VoxelizeConfig().evidence_classes == VoxelizeConfig.model_fields["evidence_classes"].default
    )  # the default, already sorted, keys the map as before
