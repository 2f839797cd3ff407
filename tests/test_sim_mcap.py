"""The simulator's MCAP output: independent readers, content, determinism, CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from sonarmap.schemas.sonar import beam_angles_from_directions
from sonarmap.schemas.topics import (
    FRAME_SONAR,
    LABEL_TOPIC,
    SONAR_TOPIC,
    TOPIC_DEAD_RECKONING,
    TOPIC_GROUND_TRUTH,
    TOPIC_TF_STATIC,
    TRUTH_ANGLE_TOPIC,
)
from sonarmap.sim.config import MissionConfig, SimConfig
from sonarmap.sim.dataset import SimRun, simulate
from sonarmap.sim.scene import load_scene

SCENES = Path(__file__).resolve().parents[1] / "configs" / "scenes"
TINY = SCENES / "tiny.yaml"


def _run(seed: int = 0, duration_s: float = 2.0) -> SimRun:
    cfg = SimConfig(mission=MissionConfig(n_goals=2, duration_s=duration_s))
    return simulate(load_scene(TINY), cfg, seed)


def _write(run: SimRun, path: Path, workers: int = 1) -> dict:
    from sonarmap.pipeline.formats.simulation import write_simulation

    return write_simulation(run, path, scene_yaml=TINY.read_text(), workers=workers)


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> tuple[SimRun, Path, dict]:
    run = _run()
    path = tmp_path_factory.mktemp("sim") / "tiny.mcap"
    return run, path, _write(run, path)


def test_every_message_decodes_with_rosbags_anyreader(written: tuple[SimRun, Path, dict]) -> None:
    from rosbags.highlevel import AnyReader

    run, path, info = written
    counts: dict[str, int] = {}
    with AnyReader([path]) as reader:
        for conn, t_ns, raw in reader.messages(connections=reader.connections):
            msg = reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
            if conn.topic == SONAR_TOPIC["horizontal"]:
                i = int((t_ns - run.trajectory["t_ns"][0]) // 500_000_000)
                ping = run.frame(i).horizontal
                img = np.asarray(msg.image.data, np.uint8).reshape(
                    len(msg.ranges), msg.image.beam_count
                )
                np.testing.assert_array_equal(img, ping.image)
                np.testing.assert_allclose(msg.ranges, ping.ranges_m)
                dirs = np.array([[d.x, d.y, d.z] for d in msg.beam_directions])
                np.testing.assert_allclose(
                    beam_angles_from_directions(dirs), ping.angles_rad, atol=1e-6
                )
                assert msg.header.frame_id == FRAME_SONAR["horizontal"]
                np.testing.assert_allclose(msg.ping_info.tx_beamwidths, np.deg2rad(20.0), rtol=1e-6)
                np.testing.assert_allclose(msg.ping_info.rx_beamwidths, np.deg2rad(1.0), rtol=1e-6)
                assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == t_ns
    n = run.n_frames
    expected = {TOPIC_TF_STATIC: 1, TOPIC_DEAD_RECKONING: n, TOPIC_GROUND_TRUTH: n}
    for s in ("horizontal", "vertical"):
        expected |= {SONAR_TOPIC[s]: n, LABEL_TOPIC[s]: n, TRUTH_ANGLE_TOPIC[s]: n}
    assert counts == expected
    assert info["messages"] == sum(expected.values())


def test_every_message_decodes_with_mcap_ros2(written: tuple[SimRun, Path, dict]) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    run, path, _ = written
    first = run.frame(0)
    seen: set[str] = set()
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _schema, channel, message, msg in reader.iter_decoded_messages():
            seen.add(channel.topic)
            if message.log_time != first.t_ns:
                continue
            if channel.topic == LABEL_TOPIC["vertical"]:
                assert msg.encoding == "mono8"
                lab = np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.width)
                np.testing.assert_array_equal(lab, first.vertical.labels)
            if channel.topic == TRUTH_ANGLE_TOPIC["horizontal"]:
                assert msg.encoding == "32FC1" and msg.step == 4 * msg.width
                ang = np.frombuffer(msg.data, np.float32).reshape(msg.height, msg.width)
                np.testing.assert_array_equal(ang, first.horizontal.truth_angle_rad)
            if channel.topic == TOPIC_GROUND_TRUTH:
                p = msg.pose.pose.position
                np.testing.assert_allclose([p.x, p.y, p.z], first.gt_pose[:3])
                q = msg.pose.pose.orientation
                assert 2 * np.arctan2(q.z, q.w) == pytest.approx(first.gt_pose[5], abs=1e-9)
            if channel.topic == TOPIC_TF_STATIC:
                tfs = {t.child_frame_id: t for t in msg.transforms}
                v = tfs[FRAME_SONAR["vertical"]].transform
                assert [v.translation.x, v.translation.y, v.translation.z] == pytest.approx(
                    [0.5, 0, 0.1]
                )
                assert [v.rotation.x, v.rotation.w] == pytest.approx([np.sqrt(0.5), np.sqrt(0.5)])
        attachments = {a.name: a for a in reader.iter_attachments()}
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert len(seen) == 9
    assert attachments["scene.ply"].data.startswith(b"ply\n")
    assert attachments["scene.yaml"].data.decode() == TINY.read_text()
    meta = metadata["sonarmap"]
    assert meta["seed"] == "0" and meta["scene"] == "tiny"
    cfg = json.loads(meta["config"])
    assert cfg["horizontal"]["n_beams"] == 512 and cfg["vertical"]["mounting"]["rpy_deg"] == [
        90.0,
        0.0,
        0.0,
    ]


def test_same_seed_same_bytes_any_workers_different_seed_differs(tmp_path: Path) -> None:
    a, b, c = tmp_path / "a.mcap", tmp_path / "b.mcap", tmp_path / "c.mcap"
    _write(_run(seed=5, duration_s=1.0), a)
    _write(_run(seed=5, duration_s=1.0), b, workers=2)
    _write(_run(seed=6, duration_s=1.0), c)
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()
    assert not list(tmp_path.glob(".*.tmp"))


def test_frames_regenerate_identically() -> None:
    run = _run(seed=2, duration_s=1.0)
    f1, f2 = run.frame(1), next(iter(list(run.frames())[1:]))
    np.testing.assert_array_equal(f1.horizontal.image, f2.horizontal.image)
    np.testing.assert_array_equal(f1.vertical.truth_angle_rad, f2.vertical.truth_angle_rad)


def test_cli_simulate_writes_mcap_and_preview(tmp_path: Path) -> None:
    from sonarmap.pipeline.cli import app

    out, png = tmp_path / "new" / "x.mcap", tmp_path / "p.png"
    args = ["simulate", "-o", str(out), "--scene", str(TINY), "--seed", "3", "--goals", "2"]
    result = CliRunner().invoke(app, [*args, "--duration-s", "1.5", "--preview", str(png), "-q"])
    assert result.exit_code == 0, result.output
    assert out.stat().st_size > 10_000
    assert png.read_bytes().startswith(b"\x89PNG")


def test_cli_simulate_bad_input_exits_2(tmp_path: Path) -> None:
    from sonarmap.pipeline.cli import app

    bad = tmp_path / "bad.yaml"
    bad.write_text("area_m: [0, 1]\n")
    runner = CliRunner()
    r1 = runner.invoke(app, ["simulate", "-o", str(tmp_path / "x.mcap"), "--scene", str(bad)])
    r2 = runner.invoke(
        app, ["simulate", "-o", str(tmp_path / "x.mcap"), "--scene", str(tmp_path / "no.yaml")]
    )
    r3 = runner.invoke(
        app, ["simulate", "-o", str(tmp_path / "bad.yaml" / "x.mcap"), "--scene", str(TINY)]
    )
    assert (r1.exit_code, r2.exit_code, r3.exit_code) == (2, 2, 2)
    assert "area_m" in r1.output


def test_template_cdr_equals_rosbags_serialisation() -> None:
    from sonarmap.pipeline.formats.frames_io import image_message
    from sonarmap.pipeline.formats.rosmsg import ros2_typestore
    from sonarmap.pipeline.formats.simulation import _FastEncoder, _Messages

    run = _run(seed=1, duration_s=1.0)
    frame = run.frame(1)
    build = _Messages(run)
    fast = _FastEncoder(run, build, 0.02)
    ts = ros2_typestore()
    t = frame.t_ns + 123
    ping = frame.vertical
    ref = ts.serialize_cdr(
        build.sonar(ping.__class__(t, "vertical", ping.image, ping.ranges_m, ping.angles_rad)),
        "marine_acoustic_msgs/msg/ProjectedSonarImage",
    )
    assert fast.image(SONAR_TOPIC["vertical"], t, ping.image) == bytes(ref)
    ref = ts.serialize_cdr(
        image_message(ping.truth_angle_rad, t, FRAME_SONAR["vertical"]),
        "sensor_msgs/msg/Image",
    )
    assert fast.image(TRUTH_ANGLE_TOPIC["vertical"], t, ping.truth_angle_rad) == bytes(ref)
    vel = np.array([0.3, -0.1])
    ref = ts.serialize_cdr(build.odometry(t, frame.dr_pose, vel, 0.02), "nav_msgs/msg/Odometry")
    assert fast.odometry(TOPIC_DEAD_RECKONING, t, frame.dr_pose, vel) == bytes(ref)
