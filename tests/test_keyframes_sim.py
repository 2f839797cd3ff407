"""The keyframes stage on simulator output, through the engine and the CLI."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.formats.frames_io import read_frames
from sonarmap.stages.keyframes import STAGE

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def sim_dataset(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    from sonarmap.pipeline.formats.simulation import write_simulation
    from sonarmap.sim.config import SimConfig
    from sonarmap.sim.dataset import simulate
    from sonarmap.sim.scene import load_scene

    scene = ROOT / "configs" / "scenes" / "tiny.yaml"
    base = SimConfig()
    mission = base.mission.model_copy(update={"n_goals": 2, "duration_s": 25.0})
    run = simulate(load_scene(scene), base.model_copy(update={"mission": mission}), 3)
    path = tmp_path_factory.mktemp("sim") / "tiny.mcap"
    write_simulation(run, path, scene_yaml=scene.read_text())
    return path, run


def _run_keyframes(dataset: Path, store: Path, overrides: tuple[str, ...] = ()) -> Path:
    from sonarmap.pipeline.engine.run.runner import execute, plan
    from sonarmap.pipeline.engine.run.session import make_context
    from sonarmap.pipeline.graph import default_graph

    ctx = make_context(
        dataset, stages=[STAGE], graph=default_graph(), overrides=overrides, store_dir=store
    )
    planned = plan(ctx.stages, ctx.config, ctx.dataset, ctx.store)
    result = execute(planned, ctx.config, ctx.dataset, ctx.store)
    return Path(result.stages[0].path)


def _reference_selection(
    t_ns: np.ndarray, pose: np.ndarray, spacing: float, rot: float, gap_ns: int
) -> list[int]:
    """Independent restatement of the keyframe rule over the simulator's own poses."""
    chosen = [0]
    for i in range(1, len(t_ns)):
        j = chosen[-1]
        d_yaw = abs((pose[i, 5] - pose[j, 5] + np.pi) % (2 * np.pi) - np.pi)
        if t_ns[i] - t_ns[j] >= gap_ns and (
            np.linalg.norm(pose[i, :3] - pose[j, :3]) >= spacing or d_yaw >= rot
        ):
            chosen.append(i)
    return chosen


@pytest.mark.parametrize("spacing", [2.0, 4.0])
def test_engine_keyframes_match_simulator_truth(
    sim_dataset: tuple[Path, Any], tmp_path: Path, spacing: float
) -> None:
    path, run = sim_dataset
    art = _run_keyframes(path, tmp_path / "store", (f"keyframes.spacing_m={spacing}",))
    table = pq.read_table(art / "keyframes.parquet")
    traj = run.trajectory
    idx = np.searchsorted(traj["t_ns"], table["t_ns"].to_numpy())
    np.testing.assert_array_equal(traj["t_ns"][idx], table["t_ns"].to_numpy())
    # Poses attached are the navigation stream at the ping times (dead reckoning, truth).
    cols = ["x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad"]
    pose = np.column_stack([table[c].to_numpy() for c in cols])
    gt = np.column_stack([table[f"gt_{c}"].to_numpy() for c in cols])
    np.testing.assert_allclose(pose, traj["dr_pose"][idx], atol=1e-9)
    np.testing.assert_allclose(gt, traj["gt_pose"][idx], atol=1e-9)
    # Count and spacing follow the rule applied to the simulator's dead-reckoning path.
    ref = _reference_selection(
        traj["t_ns"], traj["dr_pose"], spacing, np.deg2rad(30.0), 1_000_000_000
    )
    np.testing.assert_array_equal(idx, ref)
    moved = np.linalg.norm(np.diff(traj["dr_pose"][idx, :3], axis=0), axis=1)
    reasons = table["reason"].to_pylist()[1:]
    assert np.all(moved[np.array(reasons) == "translation"] >= spacing)
    assert len(table) >= 3
    # Images: exactly the simulator's pings, with labels and truth angles.
    frames = read_frames(art / "keyframes.mcap")
    assert len(frames) == len(table)
    k = len(frames) // 2
    sim_frame = run.frame(int(idx[k]))
    for s in ("horizontal", "vertical"):
        got, want = getattr(frames[k], s), getattr(sim_frame, s)
        np.testing.assert_array_equal(got.image, want.image)
        np.testing.assert_array_equal(got.labels, want.labels)
        np.testing.assert_array_equal(got.truth_angle_rad, want.truth_angle_rad)
        np.testing.assert_allclose(got.angles_rad, want.angles_rad, atol=1e-6)
    sensors = json.loads((art / "sensors.json").read_text())
    assert sensors["has_ground_truth"] and sensors["has_labels"]
    for s in ("horizontal", "vertical"):
        np.testing.assert_allclose(sensors[s]["T_base_sonar"], run.T_base_sonar[s], atol=1e-9)
    assert (art / "scene.ply").read_bytes() == run.world.to_ply_bytes()


def test_cli_topics_and_convert_on_simulator_output(
    sim_dataset: tuple[Path, Any], tmp_path: Path
) -> None:
    path, run = sim_dataset
    res = CliRunner().invoke(app, ["topics", str(path), "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    counts = {t["topic"]: t["count"] for t in doc["topics"]}
    assert counts["/sonar/horizontal"] == counts["/sonar/vertical"] == run.n_frames
    assert (
        doc["roles"]["horizontal_sonar"] == "/sonar/horizontal"
        and doc["roles"]["navigation"] == "/odometry/dead_reckoning"
    )
    out = tmp_path / "conv.mcap"
    res = CliRunner().invoke(app, ["convert", str(path), "-o", str(out), "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["topics"]["/sonar/vertical/truth_angle"] == run.n_frames
    a = pq.read_table(_run_keyframes(path, tmp_path / "s1") / "keyframes.parquet")
    b = pq.read_table(_run_keyframes(out, tmp_path / "s2") / "keyframes.parquet")
    for col in a.column_names:  # poses pass through a quaternion: equal to rounding
        if a.schema.field(col).type == "double":
            np.testing.assert_allclose(a[col].to_numpy(), b[col].to_numpy(), atol=1e-9)
        else:
            assert a[col].equals(b[col]), col


def test_cli_run_until_keyframes(sim_dataset: tuple[Path, Any], tmp_path: Path) -> None:
    try:
        from sonarmap.pipeline.graph import all_stages

        all_stages()
    except ImportError as err:
        pytest.skip(f"the full stage registry is not importable yet ({err})")
    path, _ = sim_dataset
    res = CliRunner().invoke(
        app, ["run", str(path), "--until", "keyframes", "--store", str(tmp_path / "s"), "--json"]
    )
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert [s["stage"] for s in doc["stages"]] == ["keyframes"]
