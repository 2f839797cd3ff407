"""ARIS recordings (../shared/data/aris): the maker's header layouts, beam tables and a real
6-frame file; truncated and corrupt copies are refused with one line naming the byte."""

from __future__ import annotations

import json
import re
import struct
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.readers import open_source
from sonarmap.pipeline.readers.aris import ARIS_TOPIC, ARIS_TYPE, ArisSource
from sonarmap.pipeline.readers.aris_layout import FILE_HEADER, FRAME_HEADER
from sonarmap.pipeline.readers.sonar_decode import decode_sonar
from sonarmap.pipeline.readers.sonar_models import load_sonar

_C_TYPES = {
    "uint16_t": ("u", 2),
    "uint32_t": ("u", 4),
    "int32_t": ("i", 4),
    "uint64_t": ("u", 8),
    "float": ("f", 4),
    "double": ("f", 8),
    "char": ("S", 1),
}
FRAME_BYTES = 1024 + 48 * 2000


def _struct_fields(header: Path) -> tuple[list[tuple[str, str, int, int]], dict[str, int], int]:
    """(name, kind, size, offset) of every member of the .h struct, offsets summed from
    the member sizes (packed), the header's own offset enum, and the struct's size."""
    text = header.read_text()
    body = text[text.index("struct ") : text.index("#pragma pack(pop)")]
    fields, offset = [], 0
    for ctype, name, count in re.findall(r"^\s+(\w+)\s+(\w+)(?:\[(\d+)\])?;", body, re.M):
        kind, size = _C_TYPES[ctype]
        n = int(count or 1)
        fields.append((name, kind, size, offset))
        offset += size * n
    enum = {k: int(v) for k, v in re.findall(r"Offset_(\w+)\s*=\s*(\d+)", text)}
    return fields, enum, offset


@pytest.mark.parametrize(
    ("header", "dtype"), [("FileHeader.h", FILE_HEADER), ("FrameHeader.h", FRAME_HEADER)]
)
def test_header_dtypes_match_the_makers_layout(shared_data: Path, header: str, dtype) -> None:
    fields, enum, size = _struct_fields(shared_data / "aris" / header)
    assert dtype.itemsize == size == 1024
    members = [f for f in fields if f[0] != "padding"]
    assert sorted(dtype.names) == sorted(f[0] for f in members)
    for name, kind, size, offset in members:
        sub, at = dtype.fields[name][:2]
        assert at == offset == enum[name], name
        base = sub.base if sub.shape else sub
        assert base.kind == kind and (base.itemsize == size or kind == "S"), name
        assert base.byteorder in "<|=", name


def _u32(buf: bytes, at: int) -> int:
    return struct.unpack_from("<I", buf, at)[0]


def test_sample_decodes_six_frames_with_the_makers_beam_angles(shared_data: Path) -> None:
    path = shared_data / "aris" / "sample.aris"
    buf = path.read_bytes()
    src = open_source(path)
    assert isinstance(src, ArisSource) and src.kind == "aris"
    [info] = src.topics()
    assert (info.topic, info.msgtype, info.count) == (ARIS_TOPIC, ARIS_TYPE, 6)
    # Frame 0's header starts at byte 1024; offsets from FrameHeader.h's enum:
    f0 = 1024
    assert _u32(buf, f0 + 436) == 1  # PingMode 1 -> 48 beams (FrameFuncs.c)
    assert _u32(buf, f0 + 468) == 2000  # SamplesPerBeam
    delay_us = _u32(buf, f0 + 476)  # SampleStartDelay = 4593 us
    period_us = _u32(buf, f0 + 452)  # SamplePeriod = 14 us
    c = struct.unpack_from("<f", buf, f0 + 464)[0]  # SoundSpeed = 1435.9333 m/s
    assert (delay_us, period_us) == (4593, 14) and c == pytest.approx(1435.9333, abs=1e-3)
    # WindowStart = 4593e-6 s * 1435.9333 m/s / 2 = 3.29762 m
    # last sample = (4593 + 14 * 1999) e-6 s * 1435.9333 m/s / 2 = 23.39064 m
    start_m, last_m = 4593e-6 * c / 2, (4593 + 14 * 1999) * 1e-6 * c / 2
    assert start_m == pytest.approx(3.29762, abs=1e-5)
    assert last_m == pytest.approx(23.39064, abs=1e-5)
    frames = list(src.messages([ARIS_TOPIC]))
    assert [m.index for _, _, m in frames] == list(range(6))
    # FrameTime (offset 4) is microseconds since the epoch; message times are in ns.
    t0_us = struct.unpack_from("<Q", buf, f0 + 4)[0]
    assert frames[0][1] == t0_us * 1000 == 1371198079122519000
    _, t, m = frames[0]
    ping = decode_sonar(m, ARIS_TYPE, t, "horizontal", None, str(path))
    assert ping.image.shape == (2000, 48)
    assert ping.ranges_m[0] == pytest.approx(start_m, abs=1e-5)
    assert ping.ranges_m[-1] == pytest.approx(last_m, abs=1e-4)
    # BeamWidths_ARIS1800_1200_48.h: beam 0 centre -13.5735 deg (right-most), beam 47 +13.5735.
    np.testing.assert_allclose(
        np.rad2deg(ping.angles_rad[[0, 1, -1]]), [-13.5735, -13.1419, 13.5735], atol=1e-4
    )
    # Samples are sample-major: row k holds sample k of beams 0..47.
    raw = np.frombuffer(buf, np.uint8, 48 * 2000, f0 + 1024).reshape(2000, 48)
    np.testing.assert_array_equal(ping.image, raw)
    assert ping.image.std() > 1.0
    # CompassHeading (offset 160) of frame 0 = 49.6 deg; frame 1 (header at 1024 + 97024) = 50.4.
    assert m.heading_deg == pytest.approx(struct.unpack_from("<f", buf, f0 + 160)[0])
    assert m.heading_deg == pytest.approx(49.6, abs=1e-4)
    assert frames[1][2].heading_deg == pytest.approx(50.4, abs=1e-4)
    assert m.platform is None  # the recorder left the vehicle fields at zero
    # LargeLens (offset 480) is 1: no telephoto table is bundled, and that is said.
    assert _u32(buf, f0 + 480) == 1
    assert any("telephoto" in w and "aris1800-48" in w for w in src.warnings)


def test_a_configured_beam_table_replaces_the_presets(shared_data: Path, tmp_path: Path) -> None:
    table = tmp_path / "tele.csv"
    angles = np.linspace(-7.0, 7.0, 48)
    table.write_text("angle_deg\n" + "\n".join(f"{a:.4f}" for a in angles) + "\n")
    src = open_source(shared_data / "aris" / "sample.aris")
    _, t, m = next(iter(src.messages([ARIS_TOPIC])))
    opts = type("O", (), {"horizontal_sonar": str(table)})()
    ping = decode_sonar(m, ARIS_TYPE, t, "horizontal", opts, "x")
    np.testing.assert_allclose(np.rad2deg(ping.angles_rad), angles, atol=1e-4)
    assert load_sonar(str(table)).fov_deg == pytest.approx(14.0 * 48 / 47)


def _cli(*args: str) -> tuple[int, str]:
    res = CliRunner().invoke(app, list(args))
    return res.exit_code, res.output


def test_topics_lists_and_run_refuses_in_one_line(shared_data: Path, tmp_path: Path) -> None:
    path = shared_data / "aris" / "sample.aris"
    code, out = _cli("topics", str(path), "--json")
    assert code == 0, out
    doc = json.loads(out[out.index("{") :])
    assert doc["format"] == "aris" and doc["topics"][0]["count"] == 6
    assert doc["roles"] == {"horizontal_sonar": ARIS_TOPIC}
    code, out = _cli("run", str(path), "--until", "keyframes", "--store", str(tmp_path / "s"))
    assert code == 2 and "Traceback" not in out
    [line] = [ln for ln in out.splitlines() if ln.startswith("error:")]
    assert str(path) in line and "one sonar topic" in line and ARIS_TOPIC in line


def _copy(shared_data: Path, tmp_path: Path, edit=None, size: int | None = None) -> Path:
    buf = bytearray((shared_data / "aris" / "sample.aris").read_bytes())
    if edit is not None:
        edit(buf)
    out = tmp_path / "dive.aris"
    out.write_bytes(bytes(buf[:size]))
    return out


def test_truncated_copies(shared_data: Path, tmp_path: Path) -> None:
    # Cut inside the first frame: nothing to read -> refused, naming the sizes.
    cut = _copy(shared_data, tmp_path, size=1024 + 5000)
    with pytest.raises(SourceError, match=r"dive\.aris: cut short: the first frame needs 97024"):
        open_source(cut)
    code, out = _cli("topics", str(cut))
    assert code == 2 and out.count("error:") == 1 and "Traceback" not in out
    # Cut inside frame 3: frames 0-2 read, the rest named as dropped.
    part = _copy(shared_data, tmp_path, size=1024 + 3 * FRAME_BYTES + 700)
    src = open_source(part)
    assert src.topics()[0].count == 3
    assert "700 bytes are not a whole frame" in src.warnings[0]
    for size in (0, 100, 1500):
        with pytest.raises(SourceError, match=r"dive\.aris"):
            open_source(_copy(shared_data, tmp_path, size=size))


def _put(offset: int, fmt: str, value: object):
    def edit(buf: bytearray) -> None:
        struct.pack_into(fmt, buf, offset, value)

    return edit


@pytest.mark.parametrize(
    ("offset", "fmt", "value", "message"),
    [
        (1024 + 468, "<I", 0xFFFFFFFF, r"byte 1492: SamplesPerBeam 4294967295"),
        (1024 + 436, "<I", 99, r"byte 1460: PingMode 99 is not an ARIS ping mode"),
        (1024 + 2 * FRAME_BYTES + 12, "<I", 0, r"frame 2 \(byte 195084\): Version 0x00000000"),
        (1024 + 4 * FRAME_BYTES + 516, "<I", 0, r"frame 4 \(byte 389636\): ReorderedSamples"),
        (1024 + FRAME_BYTES + 464, "<f", float("nan"), r"frame 1 \(byte 98512\): SoundSpeed nan"),
        (1024 + 3 * FRAME_BYTES + 468, "<I", 1000, r"frame 3 .*SamplesPerBeam 1000"),
    ],
)
def test_corrupt_headers_are_refused_naming_frame_and_byte(
    shared_data: Path, tmp_path: Path, offset: int, fmt: str, value: object, message: str
) -> None:
    bad = _copy(shared_data, tmp_path, _put(offset, fmt, value))
    with pytest.raises(SourceError, match=r"dive\.aris: .*" + message):
        open_source(bad)
    code, out = _cli("topics", str(bad))
    assert code == 2 and out.count("error:") == 1 and "Traceback" not in out


def test_bad_file_signature_is_not_an_aris_file(shared_data: Path, tmp_path: Path) -> None:
    buf = (shared_data / "aris" / "sample.aris").read_bytes()
    bad = tmp_path / "x.aris"
    bad.write_bytes(b"DDF\x05" + b"\x00" * 100)
    with pytest.raises(SourceError, match=r"x\.aris: 104 bytes; an ARIS file needs"):
        open_source(bad)
    bad.write_bytes(b"XXXX" + buf[4:])
    with pytest.raises(SourceError, match=r"x\.aris: not a recording sonarmap can read"):
        open_source(bad)
