"""The frames codec: KeyframeImages -> keyframes.mcap -> lazy sequence, exactly."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
from mcap.reader import make_reader

from sonarmap.pipeline.formats.frames_io import read_frames, write_frames
from sonarmap.schemas.sonar import KeyframeImages, SonarPing


def _ping(rng: np.random.Generator, t: int, sonar: str, with_truth: bool) -> SonarPing:
    n_r, n_b = 30, 16
    angles = np.sort(rng.uniform(-0.5, 0.5, n_b)).astype(np.float32)  # uneven beam table
    truth = None
    if with_truth:
        truth = rng.normal(0, 0.1, (n_r, n_b)).astype(np.float32)
        truth[rng.random((n_r, n_b)) < 0.5] = np.nan
    return SonarPing(
        t_ns=t,
        sonar=sonar,
        image=rng.integers(0, 256, (n_r, n_b), dtype=np.uint8),
        ranges_m=(1.0 + 0.1 * np.arange(n_r)).astype(np.float32),
        angles_rad=angles,
        labels=rng.integers(0, 7, (n_r, n_b), dtype=np.uint8) if with_truth else None,
        truth_angle_rad=truth,
    )


def _frames(n: int, with_truth: bool) -> list[KeyframeImages]:
    rng = np.random.default_rng(7)
    out = []
    for k in range(n):
        t = 10**18 + k * 2_000_000_000
        out.append(
            KeyframeImages(
                k,
                t,
                _ping(rng, t, "horizontal", with_truth),
                _ping(rng, t + 5, "vertical", with_truth),
                {"pair_dt_s": 5e-9},
            )
        )
    return out


def _same(a: KeyframeImages, b: KeyframeImages) -> None:
    assert (a.keyframe_id, a.t_ns, a.extras) == (b.keyframe_id, b.t_ns, b.extras)
    for s in ("horizontal", "vertical"):
        pa, pb = getattr(a, s), getattr(b, s)
        assert pa.t_ns == pb.t_ns and pb.sonar == s
        np.testing.assert_array_equal(pa.image, pb.image)
        np.testing.assert_array_equal(pa.ranges_m, pb.ranges_m)
        np.testing.assert_allclose(pa.angles_rad, pb.angles_rad, atol=2e-7)
        if pa.labels is None:
            assert pb.labels is None and pb.truth_angle_rad is None
        else:
            np.testing.assert_array_equal(pa.labels, pb.labels)
            np.testing.assert_array_equal(pa.truth_angle_rad, pb.truth_angle_rad)  # NaN == NaN here


def test_round_trip_with_and_without_labels(tmp_path: Path) -> None:
    for with_truth in (True, False):
        frames = _frames(5, with_truth)
        path = tmp_path / f"k{with_truth}.mcap"
        assert write_frames(iter(frames), path) == 5
        seq = read_frames(path)
        assert len(seq) == 5
        _same(frames[3], seq[3])
        _same(frames[-1], seq[-1])
        for a, b in zip(frames, seq, strict=True):
            _same(a, b)


def test_deterministic_bytes_and_foxglove_readable_topics(tmp_path: Path) -> None:
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    write_frames(_frames(3, True), a)
    write_frames(_frames(3, True), b)
    assert hashlib.sha256(a.read_bytes()).digest() == hashlib.sha256(b.read_bytes()).digest()
    with a.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    topics = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert topics["/sonar/horizontal"] == "marine_acoustic_msgs/msg/ProjectedSonarImage"
    assert topics["/sonar/vertical/labels"] == "sensor_msgs/msg/Image"
    assert summary.statistics.message_count == 3 * 6


def test_empty_frames(tmp_path: Path) -> None:
    path = tmp_path / "e.mcap"
    assert write_frames([], path) == 0
    assert len(read_frames(path)) == 0 and list(read_frames(path)) == []


def test_fast_cdr_codec_is_byte_identical_to_rosbags() -> None:
    """The fast ProjectedSonarImage serialiser/parser agree with rosbags' generic serde."""
    from sonarmap.pipeline.formats.frames_io import sonar_cdr, sonar_message
    from sonarmap.pipeline.formats.projected_cdr import parse_projected_cdr
    from sonarmap.pipeline.formats.rosmsg import ros2_typestore
    from sonarmap.schemas.sonar import beam_directions_from_angles

    rng = np.random.default_rng(3)
    for n_beams, frame in ((512, "sonar_horizontal"), (7, "abc"), (1, "a"), (0, "")):
        ping = SonarPing(
            1_700_000_000_123_456_789,
            "horizontal",
            rng.integers(0, 256, (30, n_beams), dtype=np.uint8),
            np.arange(30, dtype=np.float32),
            np.linspace(-1, 1, n_beams).astype(np.float32),
            frequency_hz=1.2e6 if n_beams else 0.0,  # ping_info written through
            sound_speed_m_s=1493.5 if n_beams else 0.0,
        )
        generic = bytes(
            ros2_typestore().serialize_cdr(
                sonar_message(ping, frame), "marine_acoustic_msgs/msg/ProjectedSonarImage"
            )
        )
        assert sonar_cdr(ping, frame) == generic
        t, frame_id, dirs, ranges, data, frequency, sound_speed = parse_projected_cdr(generic)
        assert (t, frame_id) == (ping.t_ns, frame)
        assert (frequency, sound_speed) == (ping.frequency_hz, ping.sound_speed_m_s)
        np.testing.assert_array_equal(
            dirs, beam_directions_from_angles(ping.angles_rad.astype(np.float64))
        )
        np.testing.assert_array_equal(ranges, ping.ranges_m)
        np.testing.assert_array_equal(data.reshape(30, n_beams), ping.image)
