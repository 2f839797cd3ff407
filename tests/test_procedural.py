"""Procedural training worlds (issue 39, item 1): deterministic, inside the area, every class."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from sonarmap.sim.procedural import ProceduralConfig, _within, generate_scene, scene_yaml
from sonarmap.sim.scene import load_scene

SEEDS = range(20)
STRUCTURE_CLASSES = {"cylindrical_piling", "rectangular_piling", "seawall", "boat_hull", "truss"}


def test_the_same_seed_gives_the_same_scene_and_another_seed_another() -> None:
    cfg = ProceduralConfig()
    assert scene_yaml(generate_scene(cfg, 11)) == scene_yaml(generate_scene(cfg, 11))
    assert scene_yaml(generate_scene(cfg, 11)) != scene_yaml(generate_scene(cfg, 12))


@pytest.mark.parametrize("seed", SEEDS)
def test_every_object_is_inside_the_area_and_every_class_is_there(seed: int) -> None:
    scene = generate_scene(ProceduralConfig(), seed)
    half = scene.area_m[1]
    primitives = scene.primitives()
    assert all(_within(p, half) for p in primitives)
    assert {p.kind for p in primitives} == STRUCTURE_CLASSES
    lo, hi = ProceduralConfig().depth_m
    assert lo <= scene.seafloor_depth_m <= hi


def test_the_ranges_are_honoured_and_layouts_vary() -> None:
    # The raw draw: opening the water (tested below) may remove a hull that blocks it.
    cfg = ProceduralConfig(
        round_radius_m=(0.3, 0.3), depth_m=(5.0, 6.0), hulls=(2, 2), open_water=False
    )
    radii, wall_angles = set(), []
    for seed in SEEDS:
        prims = generate_scene(cfg, seed).primitives()
        radii |= {
            p.radius_m
            for p in prims
            if p.kind == "cylindrical_piling" and "post" not in str(p.name)
        }
        assert sum(p.kind == "boat_hull" for p in prims) == 2
        for wall in (p for p in prims if p.kind == "seawall"):
            d = np.diff(np.asarray(wall.polyline_m), axis=0)
            wall_angles += list(np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 90)
    assert radii == {0.3}
    # Odd angles: walls are not all axis-aligned.
    assert np.mean((np.asarray(wall_angles) > 5) & (np.asarray(wall_angles) < 85)) > 0.3


def test_walls_leave_the_edge_and_none_lies_along_it() -> None:
    # Clipping walls to the area once laid 2/3 of their length onto its edge, curves
    # folded flat there (seeds 1000-1019): a wall must run inside and end at the edge.
    for seed in SEEDS:
        scene = generate_scene(ProceduralConfig(open_water=False), seed)
        limit = scene.area_m[1] - 0.5
        for wall in (p for p in scene.primitives() if p.kind == "seawall"):
            xy = np.asarray(wall.polyline_m)
            on_edge = np.abs(np.abs(xy) - limit) < 0.01
            assert not (on_edge[1:] & on_edge[:-1]).any(), (seed, wall.name)
            assert np.linalg.norm(np.diff(xy, axis=0), axis=1).sum() > 2.0


def test_a_scene_written_as_yaml_reads_back_equal(tmp_path: Path) -> None:
    scene = generate_scene(ProceduralConfig(), 3)
    path = tmp_path / "p.yaml"
    path.write_text(scene_yaml(scene))
    assert load_scene(path) == scene


def test_a_range_upside_down_is_refused() -> None:
    with pytest.raises(ValidationError, match=r"depth_m: low 9\.0 above high 4\.0"):
        ProceduralConfig(depth_m=(9.0, 4.0))


def test_the_simulator_flies_its_own_mission_through_a_generated_world() -> None:
    from sonarmap.sim.config import SimConfig
    from sonarmap.sim.dataset import simulate

    base = SimConfig()
    mission = base.mission.model_copy(update={"n_goals": 2, "duration_s": 12.0})
    run = simulate(
        generate_scene(ProceduralConfig(), 1), base.model_copy(update={"mission": mission}), 1
    )
    assert run.n_frames > 10
    seen = [run.frame(i).horizontal.labels for i in range(0, run.n_frames, 2)]
    assert any((labels > 0).any() for labels in seen if labels is not None)


@pytest.mark.parametrize("seed", range(1000, 1020))
def test_the_mission_reaches_every_goal_of_a_training_world(seed: int) -> None:
    # The default training worlds' seeds: before sim.open_water, 3 of these 20 flew 0 m
    # (start in a closed-off pocket, or every goal in another basin).
    from sonarmap.sim.config import MissionConfig
    from sonarmap.sim.mission import plan_mission
    from sonarmap.sim.open_water import free_water_pieces
    from sonarmap.sim.world import World

    scene = generate_scene(ProceduralConfig(), seed)
    mission = MissionConfig(n_goals=3)
    assert free_water_pieces(scene, mission).max() == 1
    traj = plan_mission(World(scene), mission, 10.0, np.random.default_rng([seed, 1]))
    assert len(traj.goals) == 3
    assert np.linalg.norm(np.diff(traj.waypoints, axis=0), axis=1).sum() > 25.0


def test_a_wall_across_the_area_is_opened_and_keeps_its_class() -> None:
    from sonarmap.sim.config import MissionConfig
    from sonarmap.sim.open_water import free_water_pieces, open_pockets
    from sonarmap.sim.scene import CylindricalPiling, Scene, Seawall

    wall = Seawall(name="w", polyline_m=[(-20.0, 0.0), (0.0, 1.0), (20.0, 0.0)])
    posts = [CylindricalPiling(name=f"p{i}", position_m=(-15.0 + 10 * i, 10.0)) for i in range(3)]
    scene = Scene(area_m=(-20.0, 20.0, -20.0, 20.0), objects=[wall, *posts])
    mission = MissionConfig()
    assert free_water_pieces(scene, mission).max() == 2
    opened = open_pockets(scene, mission)
    assert free_water_pieces(opened, mission).max() == 1
    walls = [p for p in opened.primitives() if p.kind == "seawall"]
    assert len(walls) == 1 and len(walls[0].polyline_m) == 2  # one segment gone, not the wall
    assert len(opened.primitives()) == 4  # the pilings far from the gap stay
