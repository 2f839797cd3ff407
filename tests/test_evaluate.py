"""evaluate: errors against the simulator's ground-truth mesh, completeness/precision,
ATE, the report and figures, and the no-ground-truth path."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from sonarmap.schemas.classes import CLASS_IDS
from sonarmap.schemas.figures import SIDE_VIEW_SCHEMA
from sonarmap.schemas.map import ERRORS_SCHEMA, MAP_SCHEMA, MAP_SORT_KEYS
from sonarmap.schemas.slam import COVARIANCE_COLUMNS, POSES_SCHEMA
from sonarmap.schemas.submaps import KEYFRAME_FRAME_ID
from sonarmap.sim.scene import load_scene
from sonarmap.sim.world import World
from sonarmap.stages.evaluate.stage import STAGE, EvaluateConfig, map_errors, surface_metrics
from sonarmap.stages.kernels.geometry import matrix_from_rpy
from sonarmap.stages.kernels.mesh_metrics import (
    ate_se2,
    mesh_distance,
    raycasting_scene,
    surface_samples,
    visible_mask,
)
from sonarmap.stages.kernels.ply import decode_mesh_ply
from sonarmap.stages.map_figures.plots import side_panels_from_table

SCENES = Path(__file__).resolve().parent.parent / "configs" / "scenes"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
T_BASE_SONAR = np.eye(4)
T_BASE_SONAR[0, 3] = 0.5
YAWS = np.arange(4) * np.pi / 2
"""Four keyframes at (0, 0, -2) m looking along +x, +y, -x, -y: every tiny-scene piling is seen."""


@functools.cache
def tiny_world() -> World:
    return World(load_scene(SCENES / "tiny.yaml"))


@functools.cache
def tiny_ply() -> bytes:
    return tiny_world().to_ply_bytes()


def map_table(xyz: np.ndarray, source: np.ndarray) -> pa.Table:
    n = len(xyz)
    t = pa.table(
        {
            "keyframe_id": np.zeros(n, np.int64),
            "frame_id": np.full(n, KEYFRAME_FRAME_ID, np.int64),
            "x_m": xyz[:, 0],
            "y_m": xyz[:, 1],
            "z_m": xyz[:, 2],
            "source": source,
            "class_name": ["cylindrical_piling"] * n,
        },
        schema=MAP_SCHEMA,
    )
    return t.sort_by([(k, "ascending") for k in MAP_SORT_KEYS])


def poses_table(xy: np.ndarray, yaw: np.ndarray) -> pa.Table:
    k = len(yaw)
    cols: dict[str, object] = {"keyframe_id": np.arange(k), "t_ns": np.arange(k) * 10**9}
    cols.update(x_m=xy[:, 0], y_m=xy[:, 1], z_m=np.full(k, -2.0), roll_rad=np.zeros(k))
    cols.update(pitch_rad=np.zeros(k), yaw_rad=yaw, **{c: np.zeros(k) for c in COVARIANCE_COLUMNS})
    return pa.table(cols, schema=POSES_SCHEMA)


def keyframes_table(dr_xy: np.ndarray, gt_xy: np.ndarray | None, yaw: np.ndarray) -> pa.Table:
    k = len(yaw)
    cols: dict[str, object] = {"keyframe_id": np.arange(k), "t_ns": np.arange(k) * 10**9}
    cols.update(x_m=dr_xy[:, 0], y_m=dr_xy[:, 1], z_m=np.full(k, -2.0), roll_rad=np.zeros(k))
    cols.update(pitch_rad=np.zeros(k), yaw_rad=yaw)
    truth = {
        "x_m": None,
        "y_m": None,
        "z_m": None,
        "roll_rad": None,
        "pitch_rad": None,
        "yaw_rad": None,
    }
    if gt_xy is not None:
        truth.update(x_m=gt_xy[:, 0], y_m=gt_xy[:, 1], z_m=np.full(k, -2.0), yaw_rad=yaw)
        truth.update(roll_rad=np.zeros(k), pitch_rad=np.zeros(k))
    for c, value in truth.items():
        cols[f"gt_{c}"] = pa.array([None] * k if value is None else value, pa.float64())
    cols["reason"] = ["first"] + ["rotation"] * (k - 1)
    return pa.table(cols)


def stage_inputs(m: pa.Table, with_truth: bool) -> dict[str, object]:
    xy = np.zeros((4, 2))
    return {
        "voxelize.map": m,
        "voxelize.summary": {
            "voxel_size_m": 0.1,
            "voxels": {"standard": 100, "semantic": 250},
            "points": {"fused": 10, "inferred": 20},
        },
        "keyframes.keyframes": keyframes_table(xy + 0.2, xy if with_truth else None, YAWS),
        "keyframes.scene_mesh": tiny_ply() if with_truth else None,
        "keyframes.sensors": {
            "horizontal": {"T_base_sonar": T_BASE_SONAR.tolist()},
            "vertical": {"T_base_sonar": T_BASE_SONAR.tolist()},
            "has_ground_truth": with_truth,
            "has_labels": True,
            "source": {"name": "tiny-test"},
        },
        "slam.poses": poses_table(xy, YAWS),
    }


def square_piling_faces() -> tuple[np.ndarray, np.ndarray]:
    """Centroids and outward unit normals of the square piling's side faces below z = -1."""
    v, t, _, cls = tiny_world().mesh_arrays()
    faces = t[cls[t[:, 0]] == CLASS_IDS["rectangular_piling"]]
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    centroid = (a + b + c) / 3
    centre = np.r_[v[faces.ravel()][:, :2].mean(axis=0), 0.0]
    n *= np.sign(np.sum((centroid - centre) * n, axis=1))[:, None]  # outward
    side = (np.abs(n[:, 2]) < 1e-6) & (centroid[:, 2] < -1)
    return centroid[side], n[side]


def test_point_on_the_mesh_has_error_zero_and_one_30cm_off_has_0_3() -> None:
    centroid, normal = square_piling_faces()
    mesh = decode_mesh_ply(tiny_ply())
    np.testing.assert_allclose(mesh_distance(mesh, centroid), 0.0, atol=1e-5)
    np.testing.assert_allclose(mesh_distance(mesh, centroid + 0.3 * normal), 0.3, atol=1e-5)


def test_stage_errors_and_precision_follow_the_offsets() -> None:
    centroid, normal = square_piling_faces()
    xyz = np.r_[centroid, centroid + 0.3 * normal]
    source = np.array(["fused"] * len(centroid) + ["inferred"] * len(centroid))
    out = STAGE.run(EvaluateConfig(), stage_inputs(map_table(xyz, source), True))
    errors: pa.Table = out["errors"]
    assert errors.schema.equals(ERRORS_SCHEMA) and errors.num_rows == len(xyz)
    e = out["metrics"]["errors"]
    assert e["fused"]["median_m"] == pytest.approx(0.0, abs=1e-5)
    assert e["inferred"]["median_m"] == pytest.approx(0.3, abs=1e-5)
    assert e["standard"]["n"] == len(centroid) and e["semantic"]["n"] == len(xyz)
    p = out["metrics"]["precision"]
    assert p["standard"] == 1.0 and p["inferred"] == 0.0 and p["semantic"] == 0.5


def completeness(xyz: np.ndarray) -> dict[str, object]:
    mesh = decode_mesh_ply(tiny_ply())
    m = map_table(xyz, np.array(["fused"] * len(xyz)))
    errors, _ = map_errors(m, mesh)
    T_world_sonar = np.stack(
        [np.r_[np.c_[matrix_from_rpy([0.0, 0.0, y]), [0, 0, -2]], [[0, 0, 0, 1]]] for y in YAWS]
    )
    comp, _, _ = surface_metrics(m, errors, mesh, T_world_sonar @ T_BASE_SONAR, EvaluateConfig())
    return comp


def test_completeness_of_a_full_surface_sampling_is_one_and_of_one_piling_less() -> None:
    dense = surface_samples(decode_mesh_ply(tiny_ply()), np.array([1, 2]), 2000.0, seed=7)
    dense = dense[(dense[:, 2] <= 0) & (dense[:, 2] > -4)]  # covers the visible band
    full = completeness(dense)
    assert full["standard"] > 0.99 and full["semantic"] > 0.99 and full["n_samples"] > 300
    # Drop the round piling at (6, 3): its share of the visible samples goes missing.
    part = completeness(dense[np.linalg.norm(dense[:, :2] - [6.0, 3.0], axis=1) > 1.0])
    assert 0.2 < part["standard"] < 0.8


def test_visibility_respects_range_fan_aperture_and_surface() -> None:
    T = np.eye(4)[None].copy()  # sonar at the origin looking along +x
    pts = np.array(
        [
            [10.0, 0.0, 0.0],  # ahead, on the surface plane: visible
            [10.0, 0.0, 0.5],  # above the surface
            [31.0, 0.0, 0.0],  # beyond 30 m
            [-10.0, 0.0, 0.0],  # behind, outside the 130 deg fan
            [10.0, 0.0, -3.0],  # 16.7 deg down, outside +-10 deg
            [5.0, 8.0, -0.5],  # 58 deg left, 3 deg down: visible
        ]
    )
    seen = visible_mask(pts, T, 30.0, np.deg2rad(65), np.deg2rad(10))
    assert seen.tolist() == [True, False, False, False, False, True]


def test_bucketing_points_by_cell_keeps_every_point_a_full_scan_sees() -> None:
    """`visible_mask` tests each keyframe against the points of nearby cells only; the
    answer must equal testing every point against every keyframe, points at the range's
    edge included."""
    rng = np.random.default_rng(11)
    poses = np.tile(np.eye(4), (12, 1, 1))
    poses[:, :3, :3] = [matrix_from_rpy([0.0, 0.0, yaw]) for yaw in rng.uniform(-3, 3, 12)]
    poses[:, :2, 3] = rng.uniform(-40, 40, (12, 2))
    poses[:, 2, 3] = -1.0
    ring = rng.uniform(-np.pi, np.pi, 400)  # points 30 m +- 1 mm from the first keyframe
    edge = poses[0, :3, 3] + np.stack(
        [np.cos(ring), np.sin(ring), np.zeros(400)], axis=1
    ) * rng.uniform(29.999, 30.001, (400, 1))
    pts = np.concatenate([rng.uniform([-80, -80, -6], [80, 80, 0.5], (20000, 3)), edge])
    full = np.zeros(len(pts), dtype=bool)
    for T in poses.astype(np.float32):  # the test of every point, without cells
        local = (pts.astype(np.float32) - T[:3, 3]) @ T[:3, :3]
        r2_xy = local[:, 0] ** 2 + local[:, 1] ** 2
        r2 = r2_xy + local[:, 2] ** 2
        full |= (
            (r2 <= 30.0**2)
            & (r2 > 0)
            & (local[:, 0] >= np.cos(np.deg2rad(65)) * np.sqrt(r2_xy))
            & (local[:, 2] ** 2 <= np.sin(np.deg2rad(10)) ** 2 * r2)
        )
    full &= pts[:, 2] <= 0
    seen = visible_mask(pts, poses, 30.0, np.deg2rad(65), np.deg2rad(10))
    assert 1000 < seen.sum() < len(pts)
    assert np.array_equal(seen, full)


def test_the_far_side_of_a_piling_is_hidden_behind_its_near_side() -> None:
    centre = np.array([6.0, 3.0, -2.0])  # the tiny scene's round piling, radius 0.25 m
    u = centre / np.linalg.norm(centre[:2]) * [1, 1, 0]
    T = np.eye(4)
    T[:3, :3] = matrix_from_rpy([0.0, 0.0, np.arctan2(3.0, 6.0)])
    T[2, 3] = -2.0
    near, far = centre - 0.25 * u, centre + 0.25 * u
    scene = raycasting_scene(decode_mesh_ply(tiny_ply()))
    pts = np.array([near, far])
    seen = visible_mask(pts, T[None], 30.0, np.deg2rad(65), np.deg2rad(10), scene)
    assert seen.tolist() == [True, False]
    assert visible_mask(pts, T[None], 30.0, np.deg2rad(65), np.deg2rad(10)).tolist() == [True, True]


def test_ate_is_zero_after_a_rigid_motion_and_the_rms_of_what_is_left() -> None:
    rng = np.random.default_rng(3)
    truth = rng.uniform(-20, 20, (50, 2))
    moved = truth @ matrix_from_rpy([0.0, 0.0, 0.7])[:2, :2].T + [4.0, -2.0]
    assert ate_se2(moved, truth) == pytest.approx(0.0, abs=1e-9)
    noise = rng.normal(0, 0.2, (50, 2))
    noise -= noise.mean(axis=0)
    assert ate_se2(truth + noise, truth) == pytest.approx(
        np.sqrt(np.mean(np.sum(noise**2, 1))), rel=0.05
    )


def _figures(inputs: dict, out: dict) -> dict:
    """The `map_figures` stage on evaluate's inputs and outputs."""
    from sonarmap.stages.map_figures import STAGE as MAP_FIGURES
    from sonarmap.stages.map_figures.stage import MapFiguresConfig

    ins = {i.name: inputs.get(i.name) for i in MAP_FIGURES.inputs if i.stage != "evaluate"}
    ins |= {"evaluate.errors": out["errors"], "evaluate.side_view": out["side_view"]}
    return dict(MAP_FIGURES.run(MapFiguresConfig(), ins))


@pytest.mark.usefixtures("no_matplotlib")
def test_report_and_figure_data_are_written_with_ground_truth_without_matplotlib() -> None:
    centroid, normal = square_piling_faces()
    xyz = np.r_[centroid, centroid + 0.05 * normal]
    source = np.array(["fused"] * len(centroid) + ["inferred"] * len(centroid))
    out = STAGE.run(EvaluateConfig(), stage_inputs(map_table(xyz, source), True))
    assert not any(name.endswith("png") for name in out)
    side = out["side_view"]
    assert side.schema.equals(SIDE_VIEW_SCHEMA) and side.num_rows > 0
    assert set(side.column("kind").to_pylist()) == {"fused", "inferred", "truth"}
    report = out["report"].decode()
    # The report names no file (its key holds the content, not the name) and says where
    # the visible surface ends (these sensors give no range: the default, said so).
    assert "tiny-test" not in report and "| standard | 10 | 100 |" in report
    assert "- visible surface: 0.0-30.0 m (the recording does not say: default)" in report
    assert ".png" not in report and "## Skipped" not in report
    traj = out["metrics"]["trajectory"]
    assert traj["slam_ate_m"] == pytest.approx(0.0, abs=1e-9)
    assert out["metrics"]["skipped"] == []
    json.dumps(out["metrics"], allow_nan=False)  # what the engine writes
    again = STAGE.run(EvaluateConfig(), stage_inputs(map_table(xyz, source), True))
    assert again["report"] == out["report"] and again["side_view"].equals(side)


def test_map_figures_draw_evaluate_s_data() -> None:
    centroid, normal = square_piling_faces()
    xyz = np.r_[centroid, centroid + 0.05 * normal]
    source = np.array(["fused"] * len(centroid) + ["inferred"] * len(centroid))
    inputs = stage_inputs(map_table(xyz, source), True)
    out = STAGE.run(EvaluateConfig(), inputs)
    figures = _figures(inputs, out)
    for name in ("errors", "map_topdown", "side_view"):
        assert figures[name][:8] == PNG_SIGNATURE and len(figures[name]) > 5000
    assert _figures(inputs, out) == figures  # the same data, the same bytes
    # The side view draws every point evaluate chose, by kind (of the piling's 10 + 10
    # points here, those within its radius + 0.3 m).
    (panel,) = side_panels_from_table(out["side_view"])
    assert (len(panel.fused_hz_m), len(panel.inferred_hz_m)) == (8, 8)
    assert len(panel.truth_hz_m) > 100 and panel.title.startswith("object ")


def test_without_ground_truth_counts_and_topdown_remain_and_skips_are_listed() -> None:
    centroid, _ = square_piling_faces()
    inputs = stage_inputs(map_table(centroid, np.array(["fused"] * len(centroid))), False)
    out = STAGE.run(EvaluateConfig(), inputs)
    m = out["metrics"]
    assert m["has_ground_truth"] is False and m["voxels"] == {"standard": 100, "semantic": 250}
    assert m["errors"] == {} and m["trajectory"] == {}
    skipped = " ".join(m["skipped"])
    for what in ("map errors", "completeness", "precision", "trajectory"):
        assert what in skipped
    assert out["errors"] is None and out["side_view"] is None
    figures = _figures(inputs, out)
    assert figures["errors"] is None and figures["side_view"] is None
    assert figures["map_topdown"][:8] == PNG_SIGNATURE
    assert "## Skipped" in out["report"].decode()
    json.dumps(m, allow_nan=False)


def test_a_map_moved_rigidly_with_its_trajectory_is_exact_after_alignment() -> None:
    centroid, _ = square_piling_faces()
    truth_xy = np.array([[-6.0, -4.0], [5.0, -3.0], [6.0, 5.0], [-4.0, 6.0]])
    R, t = matrix_from_rpy([0.0, 0.0, np.deg2rad(2.0)])[:2, :2], np.array([0.3, -0.2])
    moved = centroid.copy()
    moved[:, :2] = centroid[:, :2] @ R.T + t
    inputs = stage_inputs(map_table(moved, np.array(["fused"] * len(moved))), True)
    inputs["keyframes.keyframes"] = keyframes_table(truth_xy, truth_xy, YAWS)
    inputs["slam.poses"] = poses_table(truth_xy @ R.T + t, YAWS)
    metrics = STAGE.run(EvaluateConfig(), inputs)["metrics"]
    assert metrics["errors"]["standard"]["median_m"] > 0.1
    aligned = metrics["errors_aligned"]
    assert aligned["standard"]["median_m"] == pytest.approx(0.0, abs=1e-4)
    assert aligned["rotation_deg"] == pytest.approx(-2.0, abs=1e-6)


def test_per_class_accounting_gives_points_the_class_of_the_nearest_true_surface() -> None:
    """Fused points on the square piling, inferred ones 30 cm off it (inaccurate) and
    inferred ones on the round piling (accurate): each class gets its own figures."""
    centroid, normal = square_piling_faces()
    mesh = decode_mesh_ply(tiny_ply())
    round_pts = surface_samples(mesh, np.array([CLASS_IDS["cylindrical_piling"]]), 200.0, seed=3)
    round_pts = round_pts[(round_pts[:, 2] < -1) & (round_pts[:, 2] > -4)]
    xyz = np.r_[centroid, centroid + 0.3 * normal, round_pts]
    source = np.array(["fused"] * len(centroid) + ["inferred"] * (len(centroid) + len(round_pts)))
    m = map_table(xyz, source)
    out = STAGE.run(EvaluateConfig(), stage_inputs(m, True))
    per_class = out["metrics"]["per_class"]
    # The poses are the true ones here: the map is judged where it was made.
    assert per_class["frame"] == "ground_truth_poses" and per_class["tolerance_m"] == 0.1
    classes = per_class["classes"]
    square, rnd, whole = (
        classes["rectangular_piling"],
        classes["cylindrical_piling"],
        classes["all_structure"],
    )
    voxels = lambda p: len(np.unique(np.floor(p / 0.1).astype(np.int64), axis=0))  # noqa: E731
    assert square["standard"]["points"] == len(centroid)
    assert square["standard"]["voxels"] == voxels(centroid)
    assert square["standard"]["accurate_voxels"] == voxels(centroid)
    assert square["semantic"]["voxels"] == voxels(np.r_[centroid, centroid + 0.3 * normal])
    assert square["semantic"]["accurate_voxels"] == voxels(centroid)  # the offset ones are not
    assert square["inferred"]["median_error_m"] == pytest.approx(0.3, abs=1e-4)
    assert rnd["standard"]["voxels"] == 0 and rnd["standard"]["completeness"] == 0.0
    assert rnd["semantic"]["accurate_voxels"] == voxels(round_pts)
    assert rnd["semantic"]["completeness"] > 0.3
    assert whole["semantic"]["voxels"] == voxels(xyz)
    assert whole["visible_samples"] >= rnd["visible_samples"] + square["visible_samples"]
    assert "## Coverage by true class" in out["report"].decode()


def test_the_error_budget_is_reported_by_assigned_class() -> None:
    """`per_class["assigned_classes"]`: by the class the classifier gave (the map's
    `class_name`), the fused and inferred medians and their ratio, the per-class budget."""
    centroid, normal = square_piling_faces()
    mesh = decode_mesh_ply(tiny_ply())
    round_pts = surface_samples(mesh, np.array([CLASS_IDS["cylindrical_piling"]]), 200.0, seed=3)
    round_pts = round_pts[(round_pts[:, 2] < -1) & (round_pts[:, 2] > -4)]
    xyz = np.r_[centroid + 0.1 * normal, centroid + 0.3 * normal, round_pts]
    n = len(centroid)
    source = np.array(["fused"] * n + ["inferred"] * (n + len(round_pts)))
    assigned = ["rectangular_piling"] * (2 * n) + ["unknown"] * len(round_pts)
    m = map_table(xyz, source)
    m = m.set_column(m.schema.get_field_index("class_name"), "class_name", pa.array(assigned))
    out = STAGE.run(
        EvaluateConfig(), stage_inputs(m.sort_by([(k, "ascending") for k in MAP_SORT_KEYS]), True)
    )
    budget = out["metrics"]["per_class"]["assigned_classes"]
    square, unknown = budget["rectangular_piling"], budget["unknown"]
    assert (square["fused_points"], square["inferred_points"]) == (n, n)
    assert square["fused_median_error_m"] == pytest.approx(0.1, abs=1e-4)
    assert square["inferred_median_error_m"] == pytest.approx(0.3, abs=1e-4)
    assert square["inferred_over_fused"] == pytest.approx(3.0, abs=1e-2)
    assert unknown["fused_points"] == 0 and unknown["inferred_over_fused"] is None
    assert unknown["inferred_median_error_m"] < 0.01
    assert "### Error by assigned class" in out["report"].decode()
    json.dumps(out["metrics"], allow_nan=False)
