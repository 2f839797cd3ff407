"""evaluate's map.mcap: valid MCAP (CRCs, summary), Foxglove schema names, every message
decoded with the protobuf schema the file carries, fields read back; same input, same bytes."""

from __future__ import annotations

import io
import json
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import NonSeekingReader, make_reader

from sonarmap.schemas.classes import CLASS_IDS
from sonarmap.schemas.keyframes import KEYFRAMES_SCHEMA
from sonarmap.schemas.map import ERRORS_SCHEMA, MAP_SCHEMA
from sonarmap.schemas.slam import COVARIANCE_COLUMNS, POSES_SCHEMA
from sonarmap.schemas.sonar import KeyframeImages, SonarPing
from sonarmap.stages.evaluate.foxglove_images import fan_image
from sonarmap.stages.evaluate.foxglove_map import map_mcap
from sonarmap.stages.evaluate.foxglove_scene import TOPIC_SCHEMAS
from sonarmap.stages.kernels.ply import Mesh

K = 3
T0 = 1_700_000_000_000_000_000


def _tables() -> dict[str, Any]:
    rng = np.random.default_rng(7)
    n = 400
    m = pa.table(
        {
            "keyframe_id": rng.integers(0, K, n),
            "frame_id": np.where(rng.random(n) < 0.2, 2, -1),
            "x_m": rng.uniform(-20, 20, n),
            "y_m": rng.uniform(-20, 20, n),
            "z_m": rng.uniform(-8, 0, n),
            "source": np.where(rng.random(n) < 0.4, "inferred", "fused"),
            "class_name": rng.choice(["none", "cylindrical_piling", "unknown"], n),
        },
        schema=MAP_SCHEMA,
    )
    errors = m.append_column("error_m", pa.array(rng.uniform(0, 1, n)))
    pose = {
        "x_m": [0.0, 2.0, 4.0],
        "y_m": [0.0, 1.0, 3.0],
        "z_m": [-2.0, -2.1, -2.2],
        "roll_rad": [0.0, 0.1, 0.0],
        "pitch_rad": [0.0, 0.0, 0.1],
        "yaw_rad": [0.0, 0.7, 2.5],
    }
    t = T0 + np.arange(K) * 500_000_000
    poses = pa.table(
        {
            "keyframe_id": np.arange(K),
            "t_ns": t,
            **pose,
            **{c: np.zeros(K) for c in COVARIANCE_COLUMNS},
        },
        schema=POSES_SCHEMA,
    )
    kf = {"keyframe_id": np.arange(K), "t_ns": t, "t_vertical_ns": t}
    kf |= {"ping_index_horizontal": np.arange(K), "ping_index_vertical": np.arange(K)}
    kf |= {c: np.asarray(v) + 0.5 for c, v in pose.items()}
    kf |= {f"gt_{c}": v for c, v in pose.items()}
    kf["reason"] = ["first", "translation", "rotation"]
    keyframes = pa.table(kf, schema=KEYFRAMES_SCHEMA)
    objects = pa.table(
        {
            "keyframe_id": [0, 2],
            "object_id": [10, 11],
            "class_name": ["cylindrical_piling", "unknown"],
            "x_m": [5.0, 7.0],
            "y_m": [1.0, -2.0],
            "x_min_m": [4.8, 6.5],
            "x_max_m": [5.2, 7.5],
            "y_min_m": [0.8, -2.2],
            "y_max_m": [1.2, -1.8],
        }
    )
    ranges = np.linspace(0.5, 20.0, 80, dtype=np.float32)
    angles = np.linspace(-0.6, 0.6, 64, dtype=np.float32)

    def ping(i: int, sonar: str) -> SonarPing:
        img = rng.integers(0, 255, (80, 64), dtype=np.uint8)
        return SonarPing(int(t[i]), sonar, img, ranges, angles)

    frames = [
        KeyframeImages(i, int(t[i]), ping(i, "horizontal"), ping(i, "vertical")) for i in range(K)
    ]
    mesh = Mesh(
        np.array([[0, 0, -8], [10, 0, -8], [0, 10, -8], [10, 10, -8]], float),
        np.array([[0, 1, 2], [1, 3, 2]]),
    )
    return {
        "map_table": m,
        "errors": pa.table(errors.columns, schema=ERRORS_SCHEMA),
        "keyframes": keyframes,
        "poses": poses,
        "objects": objects,
        "frames": frames,
        "mesh": mesh,
        "T_base_sonar": np.eye(4),
    }


def _decoders(summary: Any) -> dict[int, Any]:
    """Message class per schema id, built from the FileDescriptorSet each schema carries."""
    out = {}
    for sid, schema in summary.schemas.items():
        assert schema.encoding == "protobuf"
        fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
        pool = descriptor_pool.DescriptorPool()
        for f in fds.file:
            pool.Add(f)
        out[sid] = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
    return out


def read_all(data: bytes) -> dict[str, list[Any]]:
    """Every message decoded, by topic; validates chunk and data-section CRCs on the way."""
    for _ in NonSeekingReader(io.BytesIO(data), validate_crcs=True).iter_messages():
        pass
    reader = make_reader(io.BytesIO(data), validate_crcs=True)
    summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    decoders = _decoders(summary)
    out: dict[str, list[Any]] = {}
    count = 0
    for schema, channel, message in reader.iter_messages(log_time_order=True):
        assert channel.message_encoding == "protobuf"
        assert schema.name == f"foxglove.{TOPIC_SCHEMAS[channel.topic]}"
        out.setdefault(channel.topic, []).append(decoders[schema.id].FromString(message.data))
        count += 1
    assert count == summary.statistics.message_count
    return out


def _cloud(msg: Any) -> np.ndarray:
    kinds = {1: "u1", 6: "<i4", 7: "<f4"}
    dt = np.dtype(
        {
            "names": [f.name for f in msg.fields],
            "formats": [kinds[f.type] for f in msg.fields],
            "offsets": [f.offset for f in msg.fields],
            "itemsize": msg.point_stride,
        }
    )
    return np.frombuffer(msg.data, dtype=dt)


def test_every_topic_decodes_and_reads_back() -> None:
    t = _tables()
    data = map_mcap(**t)
    assert data == map_mcap(**t)  # same inputs, same bytes
    msgs = read_all(data)
    live_only = ("/live/fused", "/map/preview", "/trajectory/preview")
    assert sorted(msgs) == sorted(k for k in TOPIC_SCHEMAS if k not in live_only)
    m, err = t["map_table"], t["errors"].column("error_m").to_numpy()
    semantic = _cloud(msgs["/map/semantic"][0])
    assert [f.name for f in msgs["/map/semantic"][0].fields] == [
        "x", "y", "z", "class_id", "source", "keyframe_id", "error",
    ]  # fmt: skip
    np.testing.assert_allclose(semantic["x"], m.column("x_m").to_numpy(), atol=1e-5)
    np.testing.assert_allclose(semantic["error"], err, atol=1e-6)
    np.testing.assert_array_equal(semantic["keyframe_id"], m.column("keyframe_id").to_numpy())
    names = np.array(m.column("class_name").to_pylist())
    assert set(semantic["class_id"][names == "cylindrical_piling"]) == {
        CLASS_IDS["cylindrical_piling"]
    }
    assert set(semantic["class_id"][names == "unknown"]) == {255}
    source = np.array(m.column("source").to_pylist())
    submap = m.column("frame_id").to_numpy() != -1
    assert set(semantic["source"][submap]) == {2}
    assert set(semantic["source"][~submap & (source == "inferred")]) == {1}
    standard = _cloud(msgs["/map/standard"][0])
    assert len(standard) == int((source == "fused").sum())
    assert msgs["/map/semantic"][0].frame_id == "map"
    assert len(msgs["/tf"]) == K
    tf = msgs["/tf"][1].transforms[0]
    assert (tf.parent_frame_id, tf.child_frame_id) == ("map", "base_link")
    assert tf.translation.x == pytest.approx(2.0)
    for topic in ("/trajectory/slam", "/trajectory/dead_reckoning", "/trajectory/ground_truth"):
        assert len(msgs[topic][0].poses) == K
    assert msgs["/trajectory/dead_reckoning"][0].poses[0].position.x == pytest.approx(0.5)
    entities = msgs["/objects"][0].entities
    assert [e.texts[0].text for e in entities] == ["cylindrical_piling", "unknown"]
    assert entities[0].cylinders[0].pose.position.x == pytest.approx(5.0)
    images = msgs["/sonar/horizontal/fan"]
    assert len(images) == K and len(msgs["/sonar/vertical/fan"]) == K
    assert (
        images[0].encoding == "mono8" and len(images[0].data) == images[0].height * images[0].step
    )
    tri = msgs["/ground_truth/mesh"][0].entities[0].triangles[0]
    assert list(tri.indices) == [0, 1, 2, 1, 3, 2] and len(tri.points) == 4


def test_without_ground_truth_or_images_no_error_field() -> None:
    t = _tables() | {"errors": None, "mesh": None, "frames": None, "objects": None}
    msgs = read_all(map_mcap(**t))
    assert "error" not in [f.name for f in msgs["/map/semantic"][0].fields]
    assert "/ground_truth/mesh" not in msgs and "/sonar/horizontal/fan" not in msgs


def test_fan_image_puts_a_bright_bin_where_its_range_and_bearing_fall() -> None:
    ranges = np.linspace(0.1, 10.0, 100, dtype=np.float32)
    angles = np.linspace(-0.5, 0.5, 51, dtype=np.float32)
    img = np.zeros((100, 51), np.uint8)
    img[49, 40] = 255  # ~5 m, +0.3 rad: left of centre
    fan = fan_image(SonarPing(0, "horizontal", img, ranges, angles), height_px=101)
    rows, cols = np.nonzero(fan)
    assert len(rows) > 0
    centre = fan.shape[1] // 2
    fwd = (100 - rows.mean()) * 0.1
    left = (centre - cols.mean()) * 0.1
    assert np.hypot(fwd, left) == pytest.approx(ranges[49], abs=0.2)
    assert np.arctan2(left, fwd) == pytest.approx(angles[40], abs=0.05)
    assert fan[0, 0] == 0 and fan[-1, centre] == 0  # outside the fan, below min range


def test_shipped_layout_is_the_sdk_layout_and_names_the_map_topics() -> None:
    from sonarmap.pipeline.formats.foxglove_layout import LAYOUT_PATH, layout_json

    text = LAYOUT_PATH.read_text()
    assert text == layout_json()  # regenerate: python -m sonarmap.pipeline.formats.foxglove_layout
    layout = json.loads(text)
    panels = [item["content"] for item in layout["content"]["items"]]
    assert panels[0]["panelType"] == "ThreeDee"
    assert set(panels[0]["config"]["topics"]) <= set(TOPIC_SCHEMAS)
    assert panels[0]["config"]["topics"]["/map/semantic"]["colorField"] == "class_id"
    images = [item["content"] for item in panels[1]["items"]]
    assert [p["panelType"] for p in images] == ["Image", "Image"]
    assert [p["config"]["imageMode"]["imageTopic"] for p in images] == [
        "/sonar/horizontal/fan",
        "/sonar/vertical/fan",
    ]
