"""Campaign 10 (evaluation figures, convert and raw captures): each test failed on the code
before its fix."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.readers import open_source
from sonarmap.pipeline.readers.oculus_raw import _PING, OCULUS_RAW_TOPIC, parse_ping
from sonarmap.pipeline.scoring import classification_scores
from sonarmap.schemas.sensors import SonarMount
from sonarmap.stages.evaluate.config import EvaluateConfig
from sonarmap.stages.evaluate.sonar_view import SonarView
from sonarmap.stages.evaluate.stage import trajectory_errors


def _field(name: str) -> int:
    return _PING.fields[name][1]


def _real(shared_data: Path) -> bytearray:
    return bytearray((shared_data / "oculus" / "one_ping_8bit.raw").read_bytes())


def _put(ping: bytearray, name: str, fmt: str, value: int) -> bytearray:
    struct.pack_into(fmt, ping, _field(name), value)
    return ping


def _refused(tmp_path: Path, data: bytes, pattern: str) -> None:
    path = tmp_path / "bad.raw"
    path.write_bytes(data)
    with pytest.raises(SourceError, match=pattern):
        open_source(path)


def test_an_unknown_data_size_is_refused_not_read_as_8_bit(
    shared_data: Path, tmp_path: Path
) -> None:
    ping = _put(_real(shared_data), "data_size", "<B", 9)
    _refused(tmp_path, bytes(ping), r"bad\.raw: ping at byte 0: dataSize 9 is none of 0-3")


def test_24_bit_samples_are_three_bytes(shared_data: Path) -> None:
    """liboculus: dataSize 2 is 24-bit, 3 bytes a sample (it was read as 4)."""
    ping = _real(shared_data)
    original, _ = parse_ping(bytes(ping))
    h = np.frombuffer(bytes(ping), _PING, 1)[0]
    n_r, n_b, start = int(h["n_ranges"]), int(h["n_beams"]), int(h["image_offset"])
    assert not int(h["flags"]) & 0x04  # no gain words in this capture
    pixels = np.frombuffer(bytes(ping), np.uint8, n_r * n_b, start).reshape(n_r, n_b)
    wide = np.zeros((n_r, n_b, 3), np.uint8)
    wide[..., 1], wide[..., 2] = 7, pixels  # value = pixel << 16 | 7 << 8
    body = bytes(ping[:start]) + wide.tobytes()
    out = bytearray(body)
    struct.pack_into("<I", out, 10, len(out) - 16)  # payloadSize
    _put(out, "data_size", "<B", 2)
    _put(out, "image_size", "<I", wide.size)
    got, end = parse_ping(bytes(out))
    assert end == len(out) and got.sample_bits == 24
    expected = (pixels.astype(np.uint32) << 16) | (7 << 8)
    np.testing.assert_array_equal(got.image, expected)
    assert original.image.shape == got.image.shape


def test_an_image_offset_inside_the_header_is_refused(shared_data: Path, tmp_path: Path) -> None:
    ping = _put(_real(shared_data), "image_offset", "<I", 0)
    _refused(tmp_path, bytes(ping), r"imageOffset 0 points inside the header")


def test_dimensions_past_the_message_name_the_fields(shared_data: Path, tmp_path: Path) -> None:
    ping = _put(_real(shared_data), "n_beams", "<H", 65535)
    _refused(tmp_path, bytes(ping), r"ping at byte 0: .*nBeams 65535")
    ping = _put(_real(shared_data), "n_ranges", "<H", 65535)
    _refused(tmp_path, bytes(ping), r"nRanges 65535 x nBeams")


def test_a_cut_second_ping_is_named_at_its_own_byte(shared_data: Path, tmp_path: Path) -> None:
    ping = bytes(_real(shared_data))
    path = tmp_path / "one-and-half.raw"
    path.write_bytes(ping + ping[:50000])
    src = open_source(path)
    assert src.topics()[0].count == 1
    assert any(f"ping at byte {len(ping)} is cut short" in w for w in src.warnings), src.warnings
    # and the times it made up are said
    assert any("stamps no ping with a clock" in w for w in src.warnings), src.warnings
    assert [t for _, t, _ in src.messages([OCULUS_RAW_TOPIC])] == [0]


def test_trajectory_error_takes_only_keyframes_with_a_pose(tmp_path: Path) -> None:
    """A keyframe missing from the poses: dead reckoning's rows were not filtered (crash)."""
    k = np.arange(5)
    keyframes = pa.table(
        {
            "keyframe_id": k,
            "gt_x_m": k * 1.0, "gt_y_m": np.zeros(5),
            "x_m": k * 1.0 + 0.1, "y_m": np.zeros(5),
        }
    )  # fmt: skip
    poses = pa.table({"keyframe_id": k[:4], "x_m": k[:4] * 1.0, "y_m": np.zeros(4)})
    got = trajectory_errors(keyframes, poses)
    assert got is not None and got["n_keyframes"] == 4
    assert got["slam_ate_m"] == pytest.approx(0.0, abs=1e-9)


def test_the_visible_surface_ends_at_the_sonars_range() -> None:
    """Completeness counted surface 30 m away for an 8 m sonar (the config's fixed range)."""
    sonar = SonarMount(np.eye(4), {"fov_deg": 90.0, "max_range_m": 8.0, "min_range_m": 1.0})
    view = SonarView.of(EvaluateConfig(), sonar)
    assert (view.max_range_m, view.min_range_m, view.fan_deg) == (8.0, 1.0, 90.0)
    assert dict(view.sources)["aperture_deg"] == "default"  # said in the report
    pts = np.array([[0.5, 0, -0.01], [5.0, 0, -0.01], [12.0, 0, -0.01]])
    assert view.visible(pts, np.eye(4)[None]).tolist() == [False, True, False]
    set_by_user = SonarView.of(EvaluateConfig(max_range_m=20.0), sonar)
    assert set_by_user.max_range_m == 20.0 and dict(set_by_user.sources)["max_range_m"] == "config"


def test_clutter_left_unknown_is_recalled() -> None:
    objects = pa.table(
        {
            "class_name": ["unknown", "unknown", "seawall"],
            "true_class_name": ["none", "none", "none"],
        }
    )
    none = classification_scores(objects)["per_class"]["none"]
    assert none["recall"] == pytest.approx(2 / 3) and none["support"] == 3


@pytest.mark.parametrize(
    ("name", "frequency_hz", "sound_speed_m_s"),
    [("oculus/one_ping_8bit.raw", 2.09888e6, 1490.66), ("aris/sample.aris", 0.0, 1435.93)],
)
def test_convert_writes_the_pings_stated_frequency_and_sound_speed(
    shared_data: Path, tmp_path: Path, name: str, frequency_hz: float, sound_speed_m_s: float
) -> None:
    """ping_info was written as 0 Hz and 0 m/s whatever the capture stated."""
    from mcap.reader import make_reader

    from sonarmap.pipeline.commands.convert import convert_recording
    from sonarmap.pipeline.formats.projected_cdr import ProjectedArrays

    out = tmp_path / "out.mcap"
    convert_recording(shared_data / name, out)
    with out.open("rb") as f:
        _, _, message = next(iter(make_reader(f).iter_messages()))
    ping = ProjectedArrays.from_cdr(message.data)
    assert ping.frequency_hz == pytest.approx(frequency_hz, rel=1e-4)
    assert ping.sound_speed_m_s == pytest.approx(sound_speed_m_s, abs=0.01)
