"""Scenes, world queries, missions and dead reckoning of the simulator."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sonarmap.schemas.classes import CLASS_IDS
from sonarmap.sim.config import MissionConfig, NavigationNoise, SimConfig
from sonarmap.sim.dataset import simulate
from sonarmap.sim.scene import Scene, SceneError, load_scene
from sonarmap.sim.world import World

SCENES = Path(__file__).resolve().parents[1] / "configs" / "scenes"


@pytest.mark.parametrize("name", ["tiny", "pier", "marina"])
def test_shipped_scenes_validate_and_mesh(name: str) -> None:
    scene = load_scene(SCENES / f"{name}.yaml")
    world = World(scene)
    assert len(world.objects) == len(scene.primitives()) + 1
    assert world.objects[-1].class_name == "seafloor"
    v, t, oid, cls = world.mesh_arrays()
    assert t.max() < len(v) and len(oid) == len(v) == len(cls)
    assert set(np.unique(oid)) == set(range(len(world.objects)))


def test_marina_has_every_class() -> None:
    kinds = {p.kind for p in load_scene(SCENES / "marina.yaml").primitives()}
    assert kinds == {"cylindrical_piling", "rectangular_piling", "seawall", "boat_hull", "truss"}


def test_scene_errors_name_the_field(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "area_m: [-5, 5, -5, 5]\nobjects:\n  - {class: cylindrical_piling, position_m: [1, 1], radius_m: -1}\n"
    )
    with pytest.raises(SceneError, match=r"objects\.0.*radius_m"):
        load_scene(bad)
    bad.write_text("area_m: [-5, 5, -5, 5]\nobjects:\n  - {class: lighthouse}\n")
    with pytest.raises(SceneError, match="lighthouse"):
        load_scene(bad)
    with pytest.raises(SceneError, match="cannot read"):
        load_scene(tmp_path / "missing.yaml")


def test_world_cast_distance_and_samples_match_geometry() -> None:
    scene = Scene.model_validate(
        {
            "area_m": [-10, 10, -10, 10],
            "seafloor_depth_m": 6.0,
            "objects": [{"class": "cylindrical_piling", "position_m": [5.0, 0.0], "radius_m": 0.5}],
        }
    )
    w = World(scene)
    hit = w.cast(
        np.array([[0.0, 0, -2], [0, 0, -2], [0, 0, -2]]),
        np.array([[1.0, 0, 0], [0, 0, -1], [0, 0, 1]]),
    )
    np.testing.assert_allclose(hit["t_hit"][:2], [4.5, 4.0], atol=1e-3)
    assert np.isinf(hit["t_hit"][2]) and hit["object_id"][2] == -1 and hit["class_id"][2] == 0
    assert list(hit["class_id"][:2]) == [CLASS_IDS["cylindrical_piling"], CLASS_IDS["seafloor"]]
    assert w.distance(np.array([[0.0, 0, -2]]), include_seafloor=False)[0] == pytest.approx(
        4.5, abs=0.02
    )
    pts = w.surface_samples(0.2, ["cylindrical_piling"])
    radial = np.hypot(pts[:, 0] - 5.0, pts[:, 1])
    side = (pts[:, 2] > -5.99) & (pts[:, 2] < 0.99)
    np.testing.assert_allclose(radial[side], 0.5, atol=0.02)
    area = 2 * np.pi * 0.5 * 7.0
    assert len(pts) == pytest.approx(area / 0.04, rel=0.2)
    ply = w.to_ply_bytes()
    assert (
        ply.startswith(b"ply\nformat binary_little_endian 1.0\n")
        and b"property int object_id" in ply
    )


def _short(n_goals: int, **nav: float) -> SimConfig:
    return SimConfig(mission=MissionConfig(n_goals=n_goals), navigation=NavigationNoise(**nav))


def test_mission_never_enters_an_object() -> None:
    scene = load_scene(SCENES / "pier.yaml")
    run = simulate(scene, _short(6), seed=4)
    m = run.config.mission
    pts = np.c_[run.path.xy, np.full(len(run.path.xy), run.path.z_m)]
    clearance = run.world.distance(pts, include_seafloor=False)
    assert clearance.min() > m.clearance_m - m.grid_resolution_m
    x0, x1, y0, y1 = scene.area_m
    assert np.all((pts[:, 0] >= x0) & (pts[:, 0] <= x1) & (pts[:, 1] >= y0) & (pts[:, 1] <= y1))
    assert len(run.path.goals) == 6
    speed = np.linalg.norm(np.diff(run.path.xy, axis=0), axis=1) * run.config.navigation.rate_hz
    assert speed.max() == pytest.approx(m.speed_m_s, rel=1e-6)
    gt = run.trajectory["gt_pose"]
    assert np.all(gt[:, 2] == -m.depth_m)


def test_duration_cuts_the_mission() -> None:
    cfg = SimConfig(mission=MissionConfig(n_goals=5, duration_s=4.0))
    run = simulate(load_scene(SCENES / "tiny.yaml"), cfg, seed=0)
    assert run.n_frames == 9
    assert np.all(np.diff(run.trajectory["t_ns"]) == 500_000_000)


def test_dead_reckoning_without_noise_is_ground_truth() -> None:
    zero = {k: 0.0 for k in NavigationNoise.model_fields if k != "rate_hz"}
    run = simulate(load_scene(SCENES / "tiny.yaml"), _short(4, **zero), seed=1)
    np.testing.assert_allclose(run.trajectory["dr_pose"], run.trajectory["gt_pose"], atol=1e-6)


def test_dead_reckoning_drift_grows_with_distance_within_noise() -> None:
    scene = Scene.model_validate({"area_m": [-40, 40, -40, 40], "objects": []})
    cfg = SimConfig(
        mission=MissionConfig(n_goals=3, min_goal_separation_m=30.0, grid_resolution_m=1.0)
    )
    ratios, first, last = [], [], []
    for seed in range(6):
        run = simulate(scene, cfg, seed=seed)
        gt, dr = run.trajectory["gt_pose"], run.trajectory["dr_pose"]
        dist = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(gt[:, :2], axis=0), axis=1))]
        err = np.linalg.norm(dr[:, :2] - gt[:, :2], axis=1)
        n = len(err)
        first.append(err[: n // 4].mean())
        last.append(err[-n // 4 :].mean())
        nav = run.config.navigation
        per_m = 3 * nav.dvl_scale_error * np.sqrt(2) + np.sin(
            np.deg2rad(
                3 * nav.yaw_bias_deg
                + 3 * nav.yaw_bias_walk_deg_sqrt_s * np.sqrt(run.path.duration_s)
            )
        )
        assert np.all(err <= per_m * dist + 0.2)
        ratios.append(err[-1] / dist[-1])
        yaw_err = np.angle(np.exp(1j * (dr[:, 5] - gt[:, 5])))
        assert np.abs(yaw_err).max() < np.deg2rad(5 * nav.yaw_bias_deg + 5 * nav.yaw_noise_deg)
    assert np.mean(last) > 2 * np.mean(first)
    assert 0.002 < np.median(ratios) < 0.1


def test_a_start_from_which_no_goal_can_be_reached_is_refused(tmp_path: Path) -> None:
    """A start in a pocket of water closed in by pilings: `simulate` wrote a 1.5 s mission
    that did not move, and `run` then found no map (campaign 12)."""
    scene = tmp_path / "forest.yaml"
    scene.write_text(
        "name: piling_forest\nseafloor_depth_m: 8.0\narea_m: [-18.0, 18.0, -18.0, 18.0]\n"
        "seafloor_margin_m: 35.0\nobjects:\n  - class: piling_grid\n    name: forest\n"
        "    origin_m: [-15.0, -15.0]\n    rows: 7\n    cols: 7\n    spacing_m: [5.0, 5.0]\n"
        "    piling: {shape: cylindrical, radius_m: 0.3}\n"
    )
    with pytest.raises(ValueError, match="no goal can be reached from the mission's start"):
        simulate(load_scene(scene), _short(6), seed=1)
