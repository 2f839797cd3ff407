"""Ingestion limits (issue 34 items 5 and 15): decompression bounded by what a chunk
declares and by a configurable limit; hostile geometry refused or dropped with a count,
naming the file, topic and time; both file-writing commands give the same file mode."""

from __future__ import annotations

import io
import os
import struct
import tracemalloc
import zlib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from mcap.records import Chunk
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.errors import ConfigError, SourceError
from sonarmap.pipeline.readers.limits import CHUNK_LIMIT_ENV
from sonarmap.pipeline.readers.mcap_scan import ChunkCorrupt, ChunkOverLimit, decompress_chunk
from sonarmap.pipeline.readers.sonar_decode import decode_image
from tests.fixtures import T0, write_recording

runner = CliRunner()
BOMB_BYTES = 64 << 20
RANGES = ((np.arange(64) + 0.5) * 0.25).astype(np.float32)


def _bomb_chunk(compression: str, declared: int, content_size: bool = True) -> Chunk:
    import lz4.frame
    import zstandard

    raw = bytes(BOMB_BYTES)
    if compression == "zstd":
        data = zstandard.ZstdCompressor(write_content_size=content_size).compress(raw)
    else:
        data = lz4.frame.compress(raw, store_size=content_size)
    return Chunk(
        message_start_time=0,
        message_end_time=0,
        uncompressed_size=declared,
        uncompressed_crc=0,
        compression=compression,
        data=data,
    )


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
@pytest.mark.parametrize("content_size", [True, False])
def test_a_bomb_is_refused_after_decompressing_only_what_it_declares(
    compression: str, content_size: bool
) -> None:
    chunk = _bomb_chunk(compression, declared=4096, content_size=content_size)
    tracemalloc.start()
    try:
        with pytest.raises(ChunkCorrupt, match="more than the 4096 bytes it declares"):
            decompress_chunk(chunk)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < BOMB_BYTES // 16, peak


def test_a_declared_size_over_the_limit_is_refused_before_decompressing(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv(CHUNK_LIMIT_ENV, "16")
    chunk = _bomb_chunk("zstd", declared=BOMB_BYTES)
    tracemalloc.start()
    try:
        with pytest.raises(ChunkOverLimit, match=f"declares {BOMB_BYTES} bytes.*{CHUNK_LIMIT_ENV}"):
            decompress_chunk(chunk)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20
    monkeypatch.setenv(CHUNK_LIMIT_ENV, "lots")
    with pytest.raises(ConfigError, match=f"{CHUNK_LIMIT_ENV}='lots'"):
        decompress_chunk(chunk)


def test_a_recording_with_a_chunk_over_the_limit_exits_2_naming_file_and_offset(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    src = tmp_path / "big.mcap"
    # 600 x 128 images (77 kB) in 4 MB chunks: one chunk declares more than 1 MiB.
    write_recording(src, n_ranges=600, n_beams=128, layout="interleaved", chunk_bytes=4 << 20)
    monkeypatch.setenv(CHUNK_LIMIT_ENV, "1")
    for path in (src, tmp_path / "cut.mcap"):
        if path.name == "cut.mcap":  # no summary: the sequential scan applies the limit too
            path.write_bytes(src.read_bytes()[: src.stat().st_size * 9 // 10])
        res = runner.invoke(app, ["convert", str(path), "-o", str(tmp_path / "out.mcap")])
        assert res.exit_code == 2, res.output
        errors = [line for line in res.stderr.splitlines() if line.startswith("error:")]
        assert len(errors) == 1 and path.name in errors[0], res.stderr
        assert "byte offset" in errors[0] and "over the limit of 1 MiB" in errors[0]
    monkeypatch.delenv(CHUNK_LIMIT_ENV)
    assert (
        runner.invoke(app, ["convert", str(src), "-o", str(tmp_path / "out.mcap")]).exit_code == 0
    )


def _bag(path: Path, compression: str) -> None:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    string = store.types["std_msgs/msg/String"]
    writer = Writer(path)
    writer.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
    with writer as w:
        conn = w.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        for k in range(200):
            data = store.serialize_ros1(string(data="x" * 1000 + str(k)), "std_msgs/msg/String")
            w.write(conn, T0 + k, data)


def _set_chunk_sizes(data: bytes, size: int) -> bytes:
    """Rewrite every chunk header's `size` field (uint32 after 'size=')."""
    out = bytearray(data)
    field = b"\x09\x00\x00\x00size="
    at = out.find(field)
    assert at >= 0
    while at >= 0:
        out[at + len(field) : at + len(field) + 4] = struct.pack("<I", size)
        at = out.find(field, at + 1)
    return bytes(out)


@pytest.mark.parametrize("compression", ["bz2", "lz4"])
def test_bag_chunks_are_bounded_by_their_declared_size(
    tmp_path: Path, compression: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    from sonarmap.pipeline.readers.ros1_source import Ros1Source

    good = tmp_path / "good.bag"
    _bag(good, compression)
    assert sum(1 for _ in Ros1Source(good).messages(["/chatter"])) == 200
    lying = tmp_path / "lying.bag"
    lying.write_bytes(_set_chunk_sizes(good.read_bytes(), 100))
    with pytest.raises(SourceError, match=r"lying.bag: bag chunk at byte offset \d+ decompresses"):
        list(Ros1Source(lying).messages(["/chatter"]))
    monkeypatch.setenv(CHUNK_LIMIT_ENV, "1")
    huge = tmp_path / "huge.bag"
    huge.write_bytes(_set_chunk_sizes(good.read_bytes(), 3 << 30))
    with pytest.raises(SourceError, match=r"huge.bag: bag chunk at byte offset \d+ declares"):
        Ros1Source(huge)


def _png(width: int, height: int) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.new("L", (4, 4)).save(buf, format="PNG")
    data = bytearray(buf.getvalue())
    ihdr = data.find(b"IHDR")
    data[ihdr + 4 : ihdr + 12] = struct.pack(">II", width, height)
    crc = zlib.crc32(bytes(data[ihdr : ihdr + 17]))
    data[ihdr + 17 : ihdr + 21] = struct.pack(">I", crc)
    return bytes(data)


def test_images_larger_than_the_limit_or_their_buffer_are_refused() -> None:
    assert decode_image(SimpleNamespace(format="png", data=_png(4, 4))).shape == (4, 4)
    with pytest.raises(ValueError, match="9000 x 9000 pixels, over the limit"):
        decode_image(SimpleNamespace(format="png", data=_png(9000, 9000)))
    with pytest.raises(ValueError, match="too large"):
        decode_image(SimpleNamespace(format="png", data=_png(100_000, 100_000)))
    raw = dict(encoding="mono8", is_bigendian=0, height=4, width=4, step=4)
    assert decode_image(SimpleNamespace(**raw, data=bytes(16))).shape == (4, 4)
    with pytest.raises(ValueError, match=r"declares 4 rows of 4 bytes.*holds 15 bytes"):
        decode_image(SimpleNamespace(**raw, data=bytes(15)))
    with pytest.raises(ValueError, match="over the limit"):
        decode_image(
            SimpleNamespace(
                **{**raw, "height": 1 << 20, "width": 1 << 20, "step": 1 << 20}, data=b""
            )
        )


def _nan_ranges() -> np.ndarray:
    r = RANGES.copy()
    r[5] = np.nan
    return r


def _jump(t: np.ndarray, xyz: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    xyz = xyz.copy()
    xyz[200:, 0] += 1000.0
    return xyz, q


def _zero_quats(t: np.ndarray, xyz: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return xyz, q * 0.0


REFUSED = {
    "nan ranges": (
        dict(ranges=_nan_ranges()),
        "/sonar/horizontal",
        "1 of 64 ranges are not finite",
    ),
    "negative ranges": (dict(ranges=RANGES - 5), "/sonar/horizontal", "negative range"),
    "descending ranges": (dict(ranges=RANGES[::-1].copy()), "/sonar/horizontal", "do not increase"),
    "ranges x 1e30": (dict(ranges=RANGES * 1e30), "/sonar/horizontal", "beyond 10000 m"),
    "infinite beam directions": (
        dict(directions=np.full((32, 3), np.inf)),
        "/sonar/horizontal",
        "32 of 32 beam directions are not finite",
    ),
    "zero beams": (dict(directions=np.zeros((0, 3))), "/sonar/horizontal", "0 beams"),
    "1x1 image": (
        dict(ranges=RANGES[:1], directions=np.array([[0.0, 0.0, 1.0]])),
        "/sonar/horizontal",
        "1 range bins x 1 beams",
    ),
    "one timestamp": (dict(same_time=True), "/sonar/horizontal", "have the same time"),
    "navigation after the pings": (
        dict(nav_offset_ns=100 * 10**9),
        "/sonar/horizontal",
        "no ping can be posed",
    ),
    "1 km navigation jump": (dict(nav=_jump), "/odometry/dead_reckoning", "jumps 1000 m"),
    "all-zero quaternions": (
        dict(nav=_zero_quats),
        "/odometry/dead_reckoning",
        "none of the 210 navigation samples",
    ),
}


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_unusable_geometry_exits_2_naming_file_topic_and_time(tmp_path: Path, case: str) -> None:
    kwargs, topic, reason = REFUSED[case]
    src = tmp_path / "hostile.mcap"
    write_recording(src, n_pings=40, **kwargs)  # type: ignore[arg-type]
    res = runner.invoke(app, ["convert", str(src), "-o", str(tmp_path / "out.mcap")])
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, res.stderr
    assert "hostile.mcap" in errors[0] and topic in errors[0] and reason in errors[0], errors[0]
    assert "t_ns=" in errors[0]
    assert not (tmp_path / "out.mcap").exists()


def test_a_bad_ping_fails_keyframes_before_anything_is_committed(tmp_path: Path) -> None:
    src = tmp_path / "nan.mcap"
    write_recording(src, n_pings=40, ranges=_nan_ranges(), bad_pings=lambda k: k == 0)
    store = tmp_path / "store"
    res = runner.invoke(app, ["run", str(src), "--store", str(store), "--until", "keyframes"])
    assert res.exit_code == 2, res.output
    assert "nan.mcap topic /sonar/horizontal" in res.stderr and "not finite" in res.stderr
    assert not list(store.glob("keyframes/*/keyframes.parquet"))


def test_bad_navigation_samples_are_dropped_with_a_count(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from sonarmap.pipeline.readers import open_recording

    def nan_quats(t: np.ndarray, xyz: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = q.copy()
        q[::3] = np.nan
        return xyz, q

    def spike(t: np.ndarray, xyz: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xyz = xyz.copy()
        xyz[100, 1] += 1000.0
        return xyz, q

    for name, hook, dropped in (
        ("nanq", nan_quats, "dropped 70 of 210"),
        ("spike", spike, "dropped 1 of 210"),
    ):
        src = tmp_path / f"{name}.mcap"
        write_recording(src, n_pings=40, nav=hook)
        rec = open_recording(src)
        nav = rec.navigation()
        assert np.isfinite(nav.xyz_m).all() and np.isfinite(nav.rpy_rad).all()
        assert np.abs(nav.xyz_m[:, 1]).max() < 1.0
        warnings = [w for w in rec.source.warnings if dropped in w]
        assert len(warnings) == 1 and "/odometry/dead_reckoning" in warnings[0], rec.source.warnings


def test_duplicate_ping_times_are_dropped_with_a_count(tmp_path: Path) -> None:
    from sonarmap.pipeline.formats.projected_cdr import serialize_projected_cdr
    from sonarmap.pipeline.formats.rosmsg import recording_writer
    from sonarmap.pipeline.readers import open_recording
    from sonarmap.schemas.sonar import beam_directions_from_angles

    src = tmp_path / "dups.mcap"
    write_recording(src, n_pings=20)
    dirs = beam_directions_from_angles(np.linspace(-0.5, 0.5, 32))
    extra = tmp_path / "extra.mcap"
    # The same recording plus a second message at an existing horizontal ping time.
    from mcap.reader import make_reader

    with src.open("rb") as f, extra.open("wb") as g, recording_writer(g) as w:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages():
            assert schema is not None
            w.write_raw(channel.topic, schema.name, bytes(message.data), message.log_time)
        image = np.zeros((64, 32), np.uint8)
        w.write_raw(
            "/sonar/horizontal",
            "marine_acoustic_msgs/msg/ProjectedSonarImage",
            serialize_projected_cdr(T0, "sonar", dirs, RANGES, image),
            T0,
        )
    rec = open_recording(extra)
    assert len(rec.ping_times_ns("horizontal")) == 20
    # Written last, the copy is also behind the clock (issue 52): dropped and counted.
    dropped = ("dropped 1 of 21 pings (duplicate", "runs backwards: dropped 1 of 21 messages")
    assert any(d in w for w in rec.source.warnings for d in dropped)


def _keyframe_times(path: Path) -> list[int]:
    from sonarmap.pipeline.readers import open_recording
    from sonarmap.stages.keyframes import STAGE, KeyframesConfig

    out = STAGE.run(KeyframesConfig(), {"dataset": open_recording(path)})
    return list(out["keyframes"].column("t_ns").to_pylist())


def test_sonarmaps_own_layout_survives_truncation(tmp_path: Path) -> None:
    src = tmp_path / "full.mcap"
    # Pings over SMALL_MESSAGE_BYTES (600 x 128), so images and navigation are apart.
    write_recording(src, n_pings=120, n_ranges=600, n_beams=128)
    full = _keyframe_times(src)
    assert len(full) >= 12
    data = src.read_bytes()
    for frac in (0.3, 0.6, 0.8, 0.95):
        cut = tmp_path / f"cut{frac}.mcap"
        cut.write_bytes(data[: int(len(data) * frac)])
        kept = _keyframe_times(cut)
        assert kept == full[: len(kept)], frac
        # Navigation is flushed every few seconds: at most ~5 s of the cut's past is lost.
        assert len(kept) >= int(frac * len(full)) - 3, (frac, len(kept), len(full))


@pytest.mark.parametrize("umask", [0o022, 0o002])
def test_convert_and_simulate_write_the_same_mode_following_the_umask(
    tmp_path: Path, umask: int
) -> None:
    src = tmp_path / "src.mcap"
    write_recording(src, n_pings=8)
    scene = Path(__file__).resolve().parents[1] / "configs" / "scenes" / "tiny.yaml"
    old = os.umask(umask)
    try:
        conv = runner.invoke(app, ["convert", str(src), "-o", str(tmp_path / "conv.mcap")])
        sim = runner.invoke(
            app,
            [
                "simulate",
                "-o",
                str(tmp_path / "sim.mcap"),
                "--scene",
                str(scene),
                "--goals",
                "2",
                "--duration-s",
                "0.5",
                "--preview",
                str(tmp_path / "p.png"),
                "-q",
            ],
        )
    finally:
        os.umask(old)
    assert conv.exit_code == 0 and sim.exit_code == 0, (conv.output, sim.output)
    for name in ("conv.mcap", "sim.mcap", "p.png"):
        assert (tmp_path / name).stat().st_mode & 0o777 == 0o666 & ~umask, name
    assert not list(tmp_path.glob(".*.tmp"))


def test_a_dropped_sample_is_one_warning_line_on_the_command_line(tmp_path: Path) -> None:
    import subprocess
    import sys

    def nan_quats(t: np.ndarray, xyz: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = q.copy()
        q[::3] = np.nan
        return xyz, q

    src = tmp_path / "nanq.mcap"
    write_recording(src, n_pings=40, nav=nan_quats)
    root = Path(__file__).resolve().parent.parent
    args = ["run", str(src), "--store", str(tmp_path / "s"), "--until", "keyframes", "-q"]
    res = subprocess.run(
        [sys.executable, "-m", "sonarmap.pipeline", *args],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(root)},
    )
    assert res.returncode == 0, res.stderr
    (line,) = [ln for ln in res.stderr.splitlines() if "navigation samples" in ln]
    assert line.startswith("warning: ") and "dropped 70 of 210 navigation samples" in line
