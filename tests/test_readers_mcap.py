"""MCAP reader: synthetic ProjectedSonarImage recordings, roles, truncation."""

from __future__ import annotations

import io
import logging
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.formats.rosmsg import Ros2McapWriter, ros2_typestore
from sonarmap.pipeline.readers import open_recording, open_source
from sonarmap.schemas.sonar import beam_directions_from_angles
from sonarmap.schemas.topics import (
    LABEL_TOPIC,
    ODOMETRY_TYPE,
    PROJECTED_SONAR_TYPE,
    SONAR_TOPIC,
    TOPIC_DEAD_RECKONING,
    TOPIC_GROUND_TRUTH,
)

T0 = 1_700_000_000_000_000_000
N_RANGES, N_BEAMS = 40, 24


def sonar_msg(t_ns: int, value: int, angles: np.ndarray) -> Any:
    """A ProjectedSonarImage whose image encodes `value` (first pixel) and a gradient."""
    types = ros2_typestore().types
    image = (np.arange(N_RANGES * N_BEAMS).reshape(N_RANGES, N_BEAMS) % 200).astype(np.uint8)
    image[0, 0] = value % 256
    dirs = beam_directions_from_angles(angles)
    return types[PROJECTED_SONAR_TYPE](
        header=types["std_msgs/msg/Header"](
            stamp=types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9),
            frame_id="sonar",
        ),
        ping_info=types["marine_acoustic_msgs/msg/PingInfo"](
            frequency=1.2e6,
            sound_speed=1500.0,
            tx_beamwidths=np.zeros(0, np.float32),
            rx_beamwidths=np.zeros(0, np.float32),
        ),
        beam_directions=[types["geometry_msgs/msg/Vector3"](x=d[0], y=d[1], z=d[2]) for d in dirs],
        ranges=((np.arange(N_RANGES) + 0.5) * 0.25).astype(np.float32),
        image=types["marine_acoustic_msgs/msg/SonarImageData"](
            is_bigendian=False, dtype=0, beam_count=N_BEAMS, data=image.reshape(-1)
        ),
    )


def odom_msg(t_ns: int, x: float, y: float, z: float, yaw: float) -> Any:
    t = ros2_typestore().types
    header = t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9),
        frame_id="odom",
    )
    pose = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=x, y=y, z=z),
        orientation=t["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=np.sin(yaw / 2), w=np.cos(yaw / 2)
        ),
    )
    twist = t["geometry_msgs/msg/Twist"](
        linear=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
        angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
    )
    return t[ODOMETRY_TYPE](
        header=header,
        child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
    )


def label_msg(t_ns: int, value: int) -> Any:
    t = ros2_typestore().types
    data = np.full((N_RANGES, N_BEAMS), value % 7, np.uint8)
    data[:, 0] = 6
    return t["sensor_msgs/msg/Image"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9),
            frame_id="s",
        ),
        height=N_RANGES,
        width=N_BEAMS,
        encoding="mono8",
        is_bigendian=0,
        step=N_BEAMS,
        data=data.reshape(-1),
    )


def trajectory(t_s: np.ndarray, speed_mps: float = 0.5) -> np.ndarray:
    """(n, 4) x, y, z, yaw: straight along x, then a left turn after 20 s."""
    x = speed_mps * np.minimum(t_s, 20.0)
    yaw = np.where(t_s > 20.0, 0.1 * (t_s - 20.0), 0.0)
    y = np.zeros_like(t_s)
    return np.column_stack([x, y, np.full_like(t_s, -2.0), yaw])


def write_synthetic(
    path: Path,
    *,
    n_pings: int = 60,
    rate_hz: float = 2.0,
    v_offset_ns: int = 3_000_000,
    labels: bool = True,
    chunk_size: int = 4 * 1024 * 1024,
    extra_sonar_topic: str | None = None,
    navigation: bool = True,
    small_message_bytes: int | None = None,
) -> dict[str, Any]:
    """A small dataset like the simulator's: both sonars, odometry (dead reckoning + truth)."""
    angles = np.deg2rad(np.linspace(-30, 30, N_BEAMS))
    ping_t = T0 + (np.arange(n_pings) * (1e9 / rate_hz)).astype(np.int64)
    nav_t = T0 + (np.arange(int(n_pings / rate_hz * 10) + 10) * 1e8).astype(np.int64) - 500_000_000
    nav = trajectory((nav_t - T0) * 1e-9)
    events: list[tuple[int, int, str, str, Any]] = []
    for k, t in enumerate(ping_t):
        events.append(
            (
                int(t),
                0,
                SONAR_TOPIC["horizontal"],
                PROJECTED_SONAR_TYPE,
                sonar_msg(int(t), k, angles),
            )
        )
        tv = int(t) + v_offset_ns
        events.append(
            (tv, 1, SONAR_TOPIC["vertical"], PROJECTED_SONAR_TYPE, sonar_msg(tv, 100 + k, angles))
        )
        if labels:
            events.append(
                (
                    int(t),
                    2,
                    LABEL_TOPIC["horizontal"],
                    "sensor_msgs/msg/Image",
                    label_msg(int(t), k),
                )
            )
            events.append(
                (tv, 3, LABEL_TOPIC["vertical"], "sensor_msgs/msg/Image", label_msg(tv, k + 1))
            )
        if extra_sonar_topic:
            events.append(
                (int(t), 4, extra_sonar_topic, PROJECTED_SONAR_TYPE, sonar_msg(int(t), k, angles))
            )
    if navigation:
        for t, (x, y, z, yaw) in zip(nav_t, nav, strict=True):
            events.append(
                (
                    int(t),
                    5,
                    TOPIC_DEAD_RECKONING,
                    ODOMETRY_TYPE,
                    odom_msg(int(t), x + 0.1, y, z, yaw),
                )
            )
            events.append(
                (int(t), 6, TOPIC_GROUND_TRUTH, ODOMETRY_TYPE, odom_msg(int(t), x, y, z, yaw))
            )
    events.sort(key=lambda e: (e[0], e[1]))
    with (
        path.open("wb") as f,
        Ros2McapWriter(f, chunk_size=chunk_size, small_message_bytes=small_message_bytes) as w,
    ):
        for t, _, topic, typ, msg in events:
            w.write(topic, typ, msg, t)
        w.add_attachment(
            "scene.ply", b"ply\nformat ascii 1.0\nend_header\n", "application/octet-stream"
        )
    return {"ping_t": ping_t, "nav_t": nav_t, "nav": nav, "angles": angles, "n": len(events)}


def all_messages(path: Path) -> list[tuple[str, int, bytes]]:
    with path.open("rb") as f:
        return [
            (c.topic, m.log_time, bytes(m.data))
            for _, c, m in make_reader(f).iter_messages(log_time_order=False)
        ]


def test_synthetic_mcap_roles_counts_and_images(tmp_path: Path) -> None:
    path = tmp_path / "d.mcap"
    info = write_synthetic(path)
    rec = open_recording(path)
    assert rec.roles.sonar == {"horizontal": "/sonar/horizontal", "vertical": "/sonar/vertical"}
    assert (
        rec.roles.navigation == TOPIC_DEAD_RECKONING
        and rec.roles.ground_truth == TOPIC_GROUND_TRUTH
    )
    assert rec.has_labels and rec.has_ground_truth
    np.testing.assert_array_equal(rec.ping_times_ns("horizontal"), info["ping_t"])
    pings = list(rec.pings("horizontal", [3, 3, 17]))
    assert [p.image[0, 0] for p in pings] == [3, 3, 17]
    assert pings[2].image.shape == (N_RANGES, N_BEAMS)
    np.testing.assert_allclose(pings[0].angles_rad, info["angles"], atol=1e-6)
    assert pings[2].labels is not None and pings[2].labels[5, 5] == 17 % 7
    nav = rec.navigation()
    np.testing.assert_array_equal(nav.t_ns, info["nav_t"])
    np.testing.assert_allclose(nav.xyz_m[:, 0], info["nav"][:, 0] + 0.1)
    assert rec.attachments()["scene.ply"].startswith(b"ply")


def test_descending_beam_table_is_sorted_with_labels(tmp_path: Path) -> None:
    """A writer with beams right-to-left: angles come back ascending, labels follow."""
    path = tmp_path / "d.mcap"
    write_synthetic(path, n_pings=4)
    # Rewrite with the beam order reversed.
    store = ros2_typestore()
    out = tmp_path / "rev.mcap"
    with path.open("rb") as f, out.open("wb") as g, Ros2McapWriter(g) as w:
        for schema, channel, m in make_reader(f).iter_messages():
            msg = store.deserialize_cdr(m.data, schema.name)
            if schema.name == PROJECTED_SONAR_TYPE:
                msg.beam_directions = msg.beam_directions[::-1]
                img = np.frombuffer(bytes(msg.image.data), np.uint8).reshape(N_RANGES, N_BEAMS)
                msg.image.data = np.ascontiguousarray(img[:, ::-1]).reshape(-1)
            elif schema.name == "sensor_msgs/msg/Image":
                img = np.frombuffer(bytes(msg.data), np.uint8).reshape(N_RANGES, N_BEAMS)
                msg.data = np.ascontiguousarray(img[:, ::-1]).reshape(-1)
            w.write(channel.topic, schema.name, msg, m.log_time)
    a = next(open_recording(path).pings("horizontal", [1]))
    b = next(open_recording(out).pings("horizontal", [1]))
    assert np.all(np.diff(b.angles_rad) > 0)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.labels, b.labels)


def test_ambiguous_and_missing_topics_name_the_config_key(tmp_path: Path) -> None:
    two = tmp_path / "two.mcap"
    write_synthetic(two, n_pings=3, extra_sonar_topic="/sonar/horizontal_copy")
    with pytest.raises(
        SourceError,
        match=r"two\.mcap: 2 candidate horizontal sonar topics.*keyframes\.horizontal_topic",
    ):
        open_recording(two)
    rec = open_recording(two, {"horizontal_topic": "/sonar/horizontal_copy"})
    assert rec.roles.sonar["horizontal"] == "/sonar/horizontal_copy"
    with pytest.raises(
        SourceError, match=r"unsupported type nav_msgs/msg/Odometry.*keyframes\.vertical_topic"
    ):
        open_recording(
            two, {"horizontal_topic": "/sonar/horizontal", "vertical_topic": TOPIC_DEAD_RECKONING}
        )
    nonav = tmp_path / "nonav.mcap"
    write_synthetic(nonav, n_pings=3, navigation=False)
    with pytest.raises(SourceError, match=r"no navigation topic.*keyframes\.navigation_topic"):
        open_recording(nonav)


def test_non_bag_and_empty_files_are_source_errors(tmp_path: Path) -> None:
    empty = tmp_path / "e.mcap"
    empty.write_bytes(b"")
    with pytest.raises(SourceError, match=r"e\.mcap: empty file"):
        open_source(empty)
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    with pytest.raises(SourceError, match=r"notes\.txt: not a recording"):
        open_source(text)


def _complete_before(path: Path, cut: int) -> int:
    """Number of messages in chunks that end at or before byte `cut` of a complete file."""
    from mcap.records import Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk

    n = 0
    with path.open("rb") as f:
        for record in StreamReader(f, emit_chunks=True).records:
            if isinstance(record, Chunk):
                if f.tell() > cut:
                    break
                n += sum(isinstance(r, Message) for r in breakup_chunk(record))
    return n


@pytest.mark.parametrize("fraction", [0.05, 0.41, 0.77, 0.97, 0.9995])
def test_truncated_mcap_keeps_every_message_before_the_cut(
    tmp_path: Path, fraction: float, caplog: Any
) -> None:
    full = tmp_path / "full.mcap"
    write_synthetic(full, n_pings=30, chunk_size=16 * 1024)
    data = full.read_bytes()
    messages = all_messages(full)
    cut = int(len(data) * fraction)
    part = tmp_path / "cut.mcap"
    part.write_bytes(data[:cut])
    with caplog.at_level(logging.WARNING):
        src = open_source(part)
    topics = sorted({m[0] for m in messages})
    got = [(topic, t) for topic, t, _ in src.messages(topics)]
    # Exactly a prefix of the file's messages: nothing invented, nothing skipped.
    assert got == [(m[0], m[1]) for m in messages[: len(got)]]
    # Every message of a chunk completed before the cut is kept, and the index agrees.
    assert len(got) >= _complete_before(full, cut)
    assert sum(len(src.times(t)) for t in topics) == len(got)
    assert f"of {cut} bytes" in caplog.text and "unreadable" in caplog.text
    unreadable = int(caplog.text.split("truncated or corrupt MCAP: ")[1].split(" of")[0])
    assert 0 < unreadable < cut


def test_polar_images_need_configured_topics_and_take_the_beam_table_from_config(
    tmp_path: Path,
) -> None:
    from PIL import Image as PILImage

    t = ros2_typestore().types
    path = tmp_path / "img.mcap"
    rng = np.random.default_rng(1)
    images = [rng.integers(0, 255, (N_RANGES, N_BEAMS), dtype=np.uint8) for _ in range(6)]
    with path.open("wb") as f, Ros2McapWriter(f) as w:
        for k in range(6):
            tk = T0 + k * 500_000_000
            header = t["std_msgs/msg/Header"](
                stamp=t["builtin_interfaces/msg/Time"](sec=tk // 10**9, nanosec=tk % 10**9),
                frame_id="s",
            )
            raw = t["sensor_msgs/msg/Image"](
                header=header,
                height=N_RANGES,
                width=N_BEAMS,
                encoding="mono8",
                is_bigendian=0,
                step=N_BEAMS,
                data=images[k].reshape(-1),
            )
            w.write("/rexrov/forward_sonar_horiz/raw_sonar", "sensor_msgs/msg/Image", raw, tk)
            buf = io.BytesIO()
            PILImage.fromarray(images[k]).save(buf, format="PNG")
            comp = t["sensor_msgs/msg/CompressedImage"](
                header=header, format="png", data=np.frombuffer(buf.getvalue(), np.uint8)
            )
            w.write(
                "/rexrov/forward_sonar_vert/raw_sonar_compressed",
                "sensor_msgs/msg/CompressedImage",
                comp,
                tk,
            )
            w.write(TOPIC_DEAD_RECKONING, ODOMETRY_TYPE, odom_msg(tk, 0.5 * k, 0.0, -2.0, 0.0), tk)
    with pytest.raises(
        SourceError, match=r"img\.mcap: no sonar topic found .*raw_sonar \[sensor_msgs/msg/Image\]"
    ):
        open_recording(path)
    options = {
        "horizontal_topic": "/rexrov/forward_sonar_horiz/raw_sonar",
        "vertical_topic": "/rexrov/forward_sonar_vert/raw_sonar_compressed",
        "image_fov_deg": 60.0,
        "image_max_range_m": 10.0,
    }
    rec = open_recording(path, options)
    h, v = next(rec.pings("horizontal", [2])), next(rec.pings("vertical", [2]))
    for ping in (h, v):
        np.testing.assert_allclose(np.rad2deg(ping.angles_rad[[0, -1]]), [-30.0, 30.0], atol=1e-4)
        np.testing.assert_allclose(ping.ranges_m[[0, -1]], [0.125, 9.875], atol=1e-6)
        np.testing.assert_array_equal(ping.image, images[2][:, ::-1])  # column 0 = port = +30 deg


def test_mcap_whose_statistics_disagree_with_its_index_is_read_sequentially(tmp_path: Path) -> None:
    """A writer that lost index entries: counts are checked, the mismatch reported, and
    every message is still read."""
    path = tmp_path / "d.mcap"
    write_synthetic(path, n_pings=6, labels=False)
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    cid = next(c for c, ch in summary.channels.items() if ch.topic == "/sonar/horizontal")
    offset = next(
        ci.message_index_offsets[cid]
        for ci in summary.chunk_indexes
        if cid in ci.message_index_offsets
    )
    data = bytearray(path.read_bytes())
    (length,) = struct.unpack_from("<Q", data, offset + 1)
    # Drop the last entry of one message index (records length 16 bytes shorter).
    (records_length,) = struct.unpack_from("<I", data, offset + 9 + 2)
    assert records_length == length - 6
    data[offset + 9 + 2 : offset + 9 + 6] = struct.pack("<I", records_length - 16)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    src = open_source(bad)
    assert any(
        "statistics and message indexes disagree for /sonar/horizontal" in w for w in src.warnings
    )
    assert len(src.times("/sonar/horizontal")) == 6
    assert len(list(src.messages(["/sonar/horizontal"]))) == 6
