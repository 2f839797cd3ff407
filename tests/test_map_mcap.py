"""map.mcap: PointCloud2 maps and /tf poses read back field by field; same input, same bytes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
from mcap.reader import make_reader

from sonarmap.pipeline.formats.map_mcap import MAP_TOPICS, TF_TOPIC, write_map_mcap
from sonarmap.pipeline.formats.rosmsg import ros2_typestore
from sonarmap.schemas.map import MAP_SCHEMA
from sonarmap.schemas.slam import COVARIANCE_COLUMNS, POSES_SCHEMA
from sonarmap.stages.kernels.geometry import matrix_from_rpy


def tables() -> tuple[pa.Table, pa.Table]:
    rng = np.random.default_rng(5)
    n = 500
    source = np.where(rng.random(n) < 0.4, "inferred", "fused")
    classes = rng.choice(["none", "cylindrical_piling", "rectangular_piling", "unknown"], n)
    m = pa.table(
        {
            "keyframe_id": rng.integers(0, 3, n),
            "frame_id": rng.integers(-1, 4, n),
            "x_m": rng.uniform(-20, 20, n),
            "y_m": rng.uniform(-20, 20, n),
            "z_m": rng.uniform(-8, 0, n),
            "source": source,
            "class_name": classes,
        },
        schema=MAP_SCHEMA,
    )
    k = 3
    poses = {"keyframe_id": np.arange(k), "t_ns": 10**9 + np.arange(k) * 5 * 10**8}
    poses.update(x_m=[0.0, 2.0, 4.0], y_m=[0.0, 1.0, 3.0], z_m=[-2.0, -2.1, -2.2])
    poses.update(roll_rad=[0.0, 0.1, -0.05], pitch_rad=[0.0, -0.02, 0.08], yaw_rad=[0.0, 0.7, 2.5])
    poses.update({c: np.zeros(k) for c in COVARIANCE_COLUMNS})
    return m, pa.table(poses, schema=POSES_SCHEMA)


def read(path: Path) -> dict[str, list[tuple[int, object]]]:
    store = ros2_typestore()
    out: dict[str, list[tuple[int, object]]] = {}
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            msg = store.deserialize_cdr(message.data, schema.name)
            out.setdefault(channel.topic, []).append((message.log_time, msg))
    return out


def test_clouds_and_poses_read_back(tmp_path: Path) -> None:
    m, poses = tables()
    path = tmp_path / "map.mcap"
    assert write_map_mcap(m, poses, path) == 5
    msgs = read(path)
    assert sorted(msgs) == sorted([*MAP_TOPICS.values(), TF_TOPIC])
    source = np.array(m.column("source").to_pylist())
    for name, rows in (("standard", source == "fused"), ("semantic", np.ones(len(source), bool))):
        [(t_ns, cloud)] = msgs[MAP_TOPICS[name]]
        assert t_ns == 2 * 10**9 and cloud.header.frame_id == "map"
        assert [f.name for f in cloud.fields] == ["x", "y", "z", "source", "class_id"]
        rec = np.frombuffer(bytes(cloud.data), dtype=np.uint8).reshape(
            cloud.width, cloud.point_step
        )
        xyz = rec[:, :12].copy().view("<f4").reshape(-1, 3)
        expected = np.c_[m.column("x_m"), m.column("y_m"), m.column("z_m")][rows]
        np.testing.assert_allclose(xyz, expected.astype(np.float32))
        np.testing.assert_array_equal(rec[:, 12], (source[rows] == "inferred").astype(np.uint8))
        classes = np.array(m.column("class_name").to_pylist())[rows]
        ids = {"none": 0, "cylindrical_piling": 1, "rectangular_piling": 2, "unknown": 255}
        np.testing.assert_array_equal(rec[:, 13], [ids[c] for c in classes])
    tfs = msgs[TF_TOPIC]
    assert [t for t, _ in tfs] == poses.column("t_ns").to_pylist()
    for (_, tf), row in zip(tfs, poses.to_pylist(), strict=True):
        tr = tf.transforms[0]
        assert tr.header.frame_id == "map" and tr.child_frame_id == "base_link"
        q = tr.transform.rotation
        x, y, z, w = q.x, q.y, q.z, q.w
        R = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
        np.testing.assert_allclose(
            R, matrix_from_rpy([row["roll_rad"], row["pitch_rad"], row["yaw_rad"]]), atol=1e-12
        )
        assert (tr.transform.translation.x, tr.transform.translation.y) == (row["x_m"], row["y_m"])


def test_same_tables_same_bytes(tmp_path: Path) -> None:
    m, poses = tables()
    write_map_mcap(m, poses, tmp_path / "a.mcap")
    write_map_mcap(m, poses, tmp_path / "b.mcap")
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
