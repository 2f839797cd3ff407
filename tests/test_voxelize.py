"""voxelize: Eq. 4 registration against an independent transform, maps without double
counting, voxel counts against a reference loop over map.parquet, PLY round trip."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import open3d as o3d
import pyarrow as pa
import pytest

from sonarmap.schemas.fused import FUSED_SCHEMA
from sonarmap.schemas.map import MAP_SCHEMA, VOXELS_SCHEMA
from sonarmap.schemas.points import POINTS_SCHEMA
from sonarmap.schemas.slam import COVARIANCE_COLUMNS, POSES_SCHEMA
from sonarmap.stages.kernels.geometry import se3_from_pose as pose_to_matrix
from sonarmap.stages.voxelize.stage import STAGE, VoxelizeConfig

T_BASE_SONAR = np.array(
    [[1.0, 0.0, 0.0, 0.5], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)
POSES = np.array(
    [
        [0.0, 0.0, -2.0, 0.0, 0.0, 0.0],
        [3.0, 1.0, -2.5, 0.05, -0.03, 0.6],
        [5.0, 4.0, -1.5, -0.02, 0.04, 2.1],
    ]
)


def poses_table(poses: np.ndarray = POSES) -> pa.Table:
    k = len(poses)
    cols: dict[str, object] = {"keyframe_id": np.arange(k), "t_ns": np.arange(k) * 10**9}
    for i, c in enumerate(("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")):
        cols[c] = poses[:, i]
    cols.update({c: np.zeros(k) for c in COVARIANCE_COLUMNS})
    return pa.table(cols, schema=POSES_SCHEMA)


def fused_table(kf: np.ndarray, xyz: np.ndarray) -> pa.Table:
    r = np.linalg.norm(xyz, axis=1)
    n = len(kf)
    return pa.table(
        {
            "keyframe_id": kf,
            "feature_id_horizontal": np.arange(n),
            "feature_id_vertical": np.arange(n),
            "range_m": r,
            "bearing_rad": np.arctan2(xyz[:, 1], xyz[:, 0]),
            "elevation_rad": np.arcsin(xyz[:, 2] / r),
            "x_m": xyz[:, 0],
            "y_m": xyz[:, 1],
            "z_m": xyz[:, 2],
            "cost": np.zeros(n),
            "confidence": np.ones(n),
        },
        schema=FUSED_SCHEMA,
    )


def points_table(kf: np.ndarray, xyz: np.ndarray, source: list[str], cls: list[str]) -> pa.Table:
    r = np.linalg.norm(xyz, axis=1)
    n = len(kf)
    return pa.table(
        {
            "keyframe_id": kf,
            "object_id": np.zeros(n, np.int64),
            "class_name": cls,
            "source": source,
            "range_m": r,
            "bearing_rad": np.arctan2(xyz[:, 1], xyz[:, 0]),
            "elevation_rad": np.arcsin(xyz[:, 2] / r),
            "x_m": xyz[:, 0],
            "y_m": xyz[:, 1],
            "z_m": xyz[:, 2],
            "confidence": np.ones(n),
        },
        schema=POINTS_SCHEMA,
    )


@pytest.fixture
def scene() -> dict[str, object]:
    """300 fused points (100 per keyframe), 40 of them classified, 60 inferred points."""
    rng = np.random.default_rng(1)
    kf = np.repeat(np.arange(3), 100)
    xyz = np.c_[rng.uniform(2, 10, 300), rng.uniform(-4, 4, 300), rng.uniform(-1.5, 2.5, 300)]
    fused = fused_table(kf, xyz)
    cls_rows = rng.choice(300, 40, replace=False)
    inf_kf = np.repeat(np.arange(3), 20)
    inf_xyz = np.c_[rng.uniform(2, 10, 60), rng.uniform(-4, 4, 60), rng.uniform(-1.5, 1.5, 60)]
    points = points_table(
        np.r_[kf[cls_rows], inf_kf],
        np.r_[xyz[cls_rows], inf_xyz],
        ["fused"] * 40 + ["inferred"] * 60,
        ["cylindrical_piling"] * 20 + ["rectangular_piling"] * 80,
    )
    return {
        "infer.points": points,
        "fuse.fused": fused,
        "slam.poses": poses_table(),
        "keyframes.sensors": {
            "horizontal": {"T_base_sonar": T_BASE_SONAR.tolist()},
            "vertical": {"T_base_sonar": T_BASE_SONAR.tolist()},
            "has_ground_truth": True,
            "has_labels": True,
        },
        "_truth": (kf, xyz, cls_rows, inf_kf, inf_xyz),
    }


def reference_world(kf: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """Eq. 4 with the simulator's own transform code, one point at a time."""
    out = []
    for k, p in zip(kf, xyz, strict=True):
        T = pose_to_matrix(POSES[k]) @ T_BASE_SONAR
        out.append(T[:3, :3] @ p + T[:3, 3])
    return np.array(out)


def sorted_rows(xyz: np.ndarray) -> np.ndarray:
    return xyz[np.lexsort(xyz.T[::-1])]


def test_points_are_registered_with_eq4_and_above_surface_dropped(scene) -> None:
    out = STAGE.run(VoxelizeConfig(), scene)
    m: pa.Table = out["map"]
    assert m.schema.equals(MAP_SCHEMA)
    kf, xyz, _, inf_kf, inf_xyz = scene["_truth"]
    world = np.r_[reference_world(kf, xyz), reference_world(inf_kf, inf_xyz)]
    below = world[world[:, 2] <= 0]
    assert 0 < len(below) < len(world)  # some points were above the surface
    got = np.c_[m.column("x_m"), m.column("y_m"), m.column("z_m")]
    np.testing.assert_allclose(sorted_rows(got), sorted_rows(below), atol=1e-9)
    dropped = out["summary"]["dropped_points"]
    assert dropped == {
        "above_surface": len(world) - len(below),
        "without_pose": 0,
        "contradicted": 0,
    }


def test_standard_map_is_all_fused_points_once_and_classes_come_from_infer(scene) -> None:
    out = STAGE.run(VoxelizeConfig(drop_above_surface=False), scene)
    m: pa.Table = out["map"]
    source = np.array(m.column("source").to_pylist())
    assert (source == "fused").sum() == 300  # fused.parquet rows, classified ones not doubled
    assert (source == "inferred").sum() == 60
    assert out["summary"]["points"] == {"fused": 300, "inferred": 60}
    cls = np.array(m.column("class_name").to_pylist())
    assert sorted(set(cls[source == "fused"])) == [
        "cylindrical_piling",
        "none",
        "rectangular_piling",
    ]
    assert (cls[source == "fused"] != "none").sum() == 40
    assert set(cls[source == "inferred"]) == {"rectangular_piling"}


def test_voxel_counts_match_a_reference_count_over_map_parquet(scene) -> None:
    size = 0.25
    out = STAGE.run(VoxelizeConfig(voxel_size_m=size), scene)
    rows = out["map"].to_pylist()
    ref: dict[str, set[tuple[int, int, int]]] = {"standard": set(), "semantic": set()}
    for r in rows:
        cell = tuple(int(np.floor(r[c] / size)) for c in ("x_m", "y_m", "z_m"))
        ref["semantic"].add(cell)
        if r["source"] == "fused":
            ref["standard"].add(cell)
    assert out["summary"]["voxels"] == {k: len(v) for k, v in ref.items()}
    vox: pa.Table = out["voxels"]
    assert vox.schema.equals(VOXELS_SCHEMA)
    for name in ("standard", "semantic"):
        v = vox.filter(pa.compute.equal(vox.column("map"), name))
        cells = set(zip(*(v.column(c).to_pylist() for c in ("ix", "iy", "iz")), strict=True))
        assert cells == ref[name]
    assert sum(
        vox.filter(pa.compute.equal(vox.column("map"), "semantic")).column("n_points").to_pylist()
    ) == len(rows)


def test_points_of_keyframes_without_pose_are_dropped(scene) -> None:
    scene = {**scene, "slam.poses": poses_table(POSES[:2])}
    out = STAGE.run(VoxelizeConfig(drop_above_surface=False), scene)
    assert set(out["map"].column("keyframe_id").to_pylist()) == {0, 1}
    assert out["summary"]["dropped_points"]["without_pose"] == 120


def test_ply_round_trips_through_open3d_and_output_is_deterministic(scene, tmp_path: Path) -> None:
    a = STAGE.run(VoxelizeConfig(), scene)
    b = STAGE.run(VoxelizeConfig(), scene)
    assert a["map"].equals(b["map"]) and a["voxels"].equals(b["voxels"])
    assert a["map_semantic"] == b["map_semantic"] and a["summary"] == b["summary"]
    json.dumps(a["summary"], allow_nan=False)  # what the engine writes
    for name in ("standard", "semantic"):
        path = tmp_path / f"{name}.ply"
        path.write_bytes(a[f"map_{name}"])
        cloud = o3d.io.read_point_cloud(str(path))
        m = a["map"]
        if name == "standard":
            m = m.filter(pa.compute.equal(m.column("source"), "fused"))
        expected = np.c_[m.column("x_m"), m.column("y_m"), m.column("z_m")]
        np.testing.assert_allclose(np.asarray(cloud.points), expected, atol=1e-5)
        colours = np.asarray(cloud.colors)
        assert colours.shape == expected.shape and np.ptp(colours, axis=0).max() > 0.3


def test_height_colours_are_matplotlib_s_viridis_without_importing_it() -> None:
    from matplotlib import colormaps

    from sonarmap.stages.kernels.colormaps import VIRIDIS_RGB8
    from sonarmap.stages.voxelize.stage import height_colours

    cmap = colormaps["viridis"]
    rgb8 = np.round(np.asarray(cmap(np.arange(cmap.N)))[:, :3] * 255.0).astype(np.uint8)
    np.testing.assert_array_equal(VIRIDIS_RGB8, rgb8)
    z = np.linspace(-3.0, 1.0, 1001)
    by_matplotlib = np.round(np.asarray(cmap((z + 3.0) / 4.0))[:, :3] * 255.0).astype(np.uint8)
    np.testing.assert_array_equal(height_colours(z), by_matplotlib)
