"""voxelize's PLYs: class id, source and keyframe id as vertex properties, read back by
`plyfile` and open3d's tensor API; without properties the bytes are those of before."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from plyfile import PlyData

from sonarmap.schemas.classes import CLASS_IDS
from sonarmap.schemas.map import MAP_SCHEMA
from sonarmap.stages.kernels.map_codes import NO_CLASS_ID, SOURCE_IDS, UNKNOWN_CLASS_ID
from sonarmap.stages.kernels.ply import encode_points_ply
from sonarmap.stages.voxelize.stage import STAGE, VoxelizeConfig


def _map_table() -> pa.Table:
    rng = np.random.default_rng(3)
    n = 300
    return pa.table(
        {
            "keyframe_id": np.sort(rng.integers(0, 40, n)),
            "frame_id": np.where(rng.random(n) < 0.25, 7, -1),
            "x_m": rng.uniform(-20, 20, n),
            "y_m": rng.uniform(-20, 20, n),
            "z_m": rng.uniform(-8, 0, n),
            "source": np.where(rng.random(n) < 0.4, "inferred", "fused"),
            "class_name": rng.choice(["none", "cylindrical_piling", "unknown", "seawall"], n),
        },
        schema=MAP_SCHEMA,
    )


def _voxelize_plys(monkeypatch: pytest.MonkeyPatch, table: pa.Table) -> dict[str, bytes]:
    """voxelize's run with its map builder returning `table` (the PLY code path is real)."""
    import sonarmap.stages.voxelize.stage as voxelize
    monkeypatch.setattr(voxelize, "build_map", lambda *a, **k: (table, {}))
    sensors = {"horizontal": {"T_base_sonar": np.eye(4).tolist()}}
    out = STAGE.run(VoxelizeConfig(), {"keyframes.sensors": sensors, **dict.fromkeys(
        ("infer.points", "fuse.fused", "slam.poses", "submaps.frames", "submaps.points")
    )})  # fmt: skip
    return {"standard": out["map_standard"], "semantic": out["map_semantic"]}


def test_plyfile_reads_class_source_and_keyframe(monkeypatch: pytest.MonkeyPatch) -> None:
    table = _map_table()
    plys = _voxelize_plys(monkeypatch, table)
    vertex = PlyData.read(io.BytesIO(plys["semantic"]))["vertex"]
    names = [p.name for p in vertex.properties]
    assert names == ["x", "y", "z", "red", "green", "blue", "class_id", "source", "keyframe_id"]
    np.testing.assert_allclose(vertex["x"], table.column("x_m").to_numpy(), atol=1e-5)
    np.testing.assert_array_equal(vertex["keyframe_id"], table.column("keyframe_id").to_numpy())
    cls = np.array(table.column("class_name").to_pylist())
    expected = {
        "none": NO_CLASS_ID,
        "unknown": UNKNOWN_CLASS_ID,
        "cylindrical_piling": CLASS_IDS["cylindrical_piling"],
        "seawall": CLASS_IDS["seawall"],
    }
    for name, cid in expected.items():
        assert set(vertex["class_id"][cls == name]) == {cid}
    src = np.array(table.column("source").to_pylist())
    submap = table.column("frame_id").to_numpy() != -1
    assert set(vertex["source"][submap]) == {SOURCE_IDS["submap"]}
    assert set(vertex["source"][~submap & (src == "inferred")]) == {SOURCE_IDS["inferred"]}
    assert set(vertex["source"][~submap & (src == "fused")]) == {SOURCE_IDS["fused"]}
    standard = PlyData.read(io.BytesIO(plys["standard"]))["vertex"]
    assert standard.count == int((src == "fused").sum())


def test_open3d_tensor_api_reads_the_properties(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    o3d = pytest.importorskip("open3d")
    table = _map_table()
    path = tmp_path / "semantic.ply"
    path.write_bytes(_voxelize_plys(monkeypatch, table)["semantic"])
    cloud = o3d.t.io.read_point_cloud(str(path))
    assert len(cloud.point.positions) == table.num_rows
    kf = cloud.point["keyframe_id"].numpy().reshape(-1)
    np.testing.assert_array_equal(kf, table.column("keyframe_id").to_numpy())
    assert set(np.unique(cloud.point["source"].numpy())) <= set(SOURCE_IDS.values())


def test_writer_without_properties_keeps_the_old_layout() -> None:
    xyz = np.array([[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]])
    rgb = np.array([[1, 2, 3], [4, 5, 6]], np.uint8)
    data = encode_points_ply(xyz, rgb, "hello")
    header = (
        b"ply\nformat binary_little_endian 1.0\ncomment hello\nelement vertex 2\n"
        b"property float x\nproperty float y\nproperty float z\nproperty uchar red\n"
        b"property uchar green\nproperty uchar blue\nend_header\n"
    )
    body = np.zeros(2, "<f4,<f4,<f4,u1,u1,u1")
    for i in range(3):
        body[f"f{i}"] = xyz[:, i]
        body[f"f{i + 3}"] = rgb[:, i]
    assert data == header + body.tobytes()
    assert encode_points_ply(xyz, rgb, "hello", {}) == data


def test_property_of_another_length_is_refused() -> None:
    with pytest.raises(ValueError, match="property"):
        encode_points_ply(np.zeros((2, 3)), np.zeros((2, 3), np.uint8), "x", {"a": np.zeros(3)})
