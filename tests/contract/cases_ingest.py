"""Hostile recordings for ingestion (issue 34 items 5 and 15, "no empty map in silence",
sonarmap's own MCAP layout cut short): decompression bombs and lying chunk sizes, bag
chunks declaring gigabytes, unusable sonar geometry and navigation, truncated copies.

Recordings are written in the work directory by `tests.fixtures.write_recording`; bombs are
built by substituting a chunk's zstd payload while the MCAP writer runs, so the rest of
the file (indexes, summary) stays valid and the reader meets the bomb where a run would.
"""

from __future__ import annotations

import functools
import struct
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from tests.contract.case import Case, names
from tests.fixtures import write_recording

RANGES = ((np.arange(64) + 0.5) * 0.25).astype(np.float32)
GiB = 1 << 30


@functools.cache
def _zstd_frame(n_bytes: int, content_size: bool) -> bytes:
    """A zstd frame of `n_bytes` zeros (a few tens of kB), compressed in pieces."""
    import zstandard

    comp = zstandard.ZstdCompressor(level=1, write_content_size=content_size)
    obj = comp.compressobj(size=n_bytes if content_size else -1)
    piece = bytes(16 << 20)
    parts = [obj.compress(piece) for _ in range(n_bytes // len(piece))]
    parts.append(obj.compress(piece[: n_bytes % len(piece)]))
    parts.append(obj.flush())
    return b"".join(parts)


def _bomb_recording(
    path: Path,
    expands_to: int,
    chunks: tuple[int, ...] = (0,),
    declare: int | None = None,
    content_size: bool = False,
) -> None:
    """An interleaved recording whose chunks `chunks` hold a zstd frame expanding to
    `expands_to` bytes; with `declare`, their records also declare that size."""
    import mcap.writer as mw
    from mcap.reader import make_reader

    real = mw.zstandard
    calls = {"n": 0}

    class _Shim:
        @staticmethod
        def compress(data: bytes) -> bytes:
            k = calls["n"]
            calls["n"] += 1
            return _zstd_frame(expands_to, content_size) if k in chunks else real.compress(data)

        def __getattr__(self, name: str) -> Any:
            return getattr(real, name)

    mw.zstandard = _Shim()  # type: ignore[assignment]
    try:
        write_recording(path, n_pings=40, n_ranges=600, n_beams=128, layout="interleaved")
    finally:
        mw.zstandard = real
    if declare is None:
        return
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    offsets = sorted(c.chunk_start_offset for c in summary.chunk_indexes)
    data = bytearray(path.read_bytes())
    for k in chunks:
        # Chunk record: opcode, length, start time, end time, then uncompressed_size.
        struct.pack_into("<Q", data, offsets[k] + 1 + 8 + 16, declare)
    path.write_bytes(bytes(data))


def _bomb(name: str, **kwargs: Any) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        _bomb_recording(work / name, **kwargs)
        return ["run", name]

    return build


def _cut_bomb(work: Path) -> list[str]:
    _bomb_recording(work / "full.mcap", expands_to=2 * GiB)
    data = (work / "full.mcap").read_bytes()
    (work / "cut.mcap").write_bytes(data[: len(data) * 3 // 4])
    return ["run", "cut.mcap"]


def _normal(work: Path) -> list[str]:
    write_recording(
        work / "big.mcap", n_ranges=600, n_beams=128, layout="interleaved", chunk_bytes=4 << 20
    )
    return ["run", "big.mcap", "--until", "keyframes"]


def _bag(work: Path, declare: int) -> list[str]:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    string = store.types["std_msgs/msg/String"]
    writer = Writer(work / "lying.bag")
    writer.set_compression(Writer.CompressionFormat.BZ2)
    with writer as w:
        conn = w.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        for k in range(100):
            w.write(
                conn,
                10**18 + k,
                store.serialize_ros1(string(data="x" * 900), "std_msgs/msg/String"),
            )
    data = bytearray((work / "lying.bag").read_bytes())
    field = b"\x09\x00\x00\x00size="
    at = data.find(field)
    while at >= 0:
        struct.pack_into("<I", data, at + len(field), declare)
        at = data.find(field, at + 1)
    (work / "lying.bag").write_bytes(bytes(data))
    return ["topics", "lying.bag"]


RESOURCES = [
    Case(
        "resources",
        "zstd bomb: 2 GiB frame in a chunk declaring ~256 kB",
        _bomb("b.mcap", expands_to=2 * GiB),
        check=names("b.mcap", "byte offset", "more than"),
    ),
    Case(
        "resources",
        "zstd bomb with a 2 GiB frame content size",
        _bomb("b.mcap", expands_to=2 * GiB, content_size=True),
        check=names("b.mcap", "byte offset"),
    ),
    Case(
        "resources",
        "consistent 1 GiB chunk (declared and real)",
        _bomb("b.mcap", expands_to=GiB, declare=GiB, content_size=True),
        check=names("b.mcap", "byte offset", "over the limit"),
    ),
    Case(
        "resources",
        "four consistent 1 GiB chunks",
        _bomb("b.mcap", expands_to=GiB, chunks=(0, 1, 2, 3), declare=GiB),
        check=names("over the limit"),
    ),
    Case(
        "resources",
        "chunk declaring 8 GiB, small payload",
        _bomb("b.mcap", expands_to=1 << 20, declare=8 * GiB),
        check=names("over the limit"),
    ),
    Case(
        "resources",
        "consistent 200 MiB chunks under the limit, CRC wrong",
        _bomb("b.mcap", expands_to=200 << 20, chunks=(0, 1), declare=200 << 20, content_size=True),
    ),
    Case("resources", "cut copy of a zstd bomb (sequential scan)", _cut_bomb, expect_exit=(0, 2)),
    Case(
        "resources",
        "SONARMAP_MAX_CHUNK_MB=1 on 4 MB chunks",
        _normal,
        env={"SONARMAP_MAX_CHUNK_MB": "1"},
        check=names("SONARMAP_MAX_CHUNK_MB"),
    ),
    Case(
        "resources",
        "SONARMAP_MAX_CHUNK_MB=junk",
        _normal,
        env={"SONARMAP_MAX_CHUNK_MB": "junk"},
        check=names("SONARMAP_MAX_CHUNK_MB"),
    ),
    Case(
        "resources",
        "ROS 1 bag chunk declaring 3 GiB",
        lambda w: _bag(w, 3 * GiB),
        check=names("lying.bag", "declares"),
    ),
    Case(
        "resources",
        "ROS 1 bag chunk declaring 100 bytes (bz2 bomb)",
        lambda w: _bag(w, 100),
        expect_exit=(0, 2),
    ),
]


def _rec(name: str, run_args: tuple[str, ...] = (), **kwargs: Any) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        write_recording(work / name, **kwargs)
        return ["run", name, *run_args]

    return build


def _nan(r: np.ndarray, at: int = 5) -> np.ndarray:
    r = r.copy()
    r[at] = np.nan
    return r


def _nav(fn: Callable[[np.ndarray, np.ndarray], None], quats: bool = False) -> Callable[..., Any]:
    def hook(t: np.ndarray, xyz: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xyz, q = xyz.copy(), q.copy()
        fn(q if quats else xyz, t)
        return xyz, q

    return hook


def _set(index: Any, value: float) -> Callable[[np.ndarray, np.ndarray], None]:
    def fn(a: np.ndarray, _: np.ndarray) -> None:
        a[index] = value

    return fn


def _add(index: Any, value: float) -> Callable[[np.ndarray, np.ndarray], None]:
    def fn(a: np.ndarray, _: np.ndarray) -> None:
        a[index] += value

    return fn


H = "/sonar/horizontal"
NAV = "/odometry/dead_reckoning"
DIRS = np.tile([0.0, 0.0, 1.0], (32, 1))
REFUSED: list[tuple[str, dict[str, Any], tuple[str, ...]]] = [
    ("NaN range", dict(ranges=_nan(RANGES)), (H, "t_ns=", "not finite")),
    (
        "+inf range",
        dict(ranges=np.where(np.arange(64) == 63, np.inf, RANGES).astype(np.float32)),
        (H, "t_ns="),
    ),
    (
        "NaN range in a later keyframe only",
        dict(ranges=_nan(RANGES), bad_pings=lambda k: k >= 16),
        (H, "t_ns="),
    ),
    ("negative ranges", dict(ranges=RANGES - 5), (H, "negative")),
    ("descending ranges", dict(ranges=RANGES[::-1].copy()), (H, "increase")),
    ("ranges x 1e30", dict(ranges=RANGES * 1e30), (H, "t_ns=")),
    ("ranges x 1e6 (250 km)", dict(ranges=RANGES * 1e6), (H, "beyond")),
    ("infinite beam directions", dict(directions=np.full((32, 3), np.inf)), (H, "beam directions")),
    (
        "one infinite beam direction",
        dict(directions=np.vstack([DIRS[:31], [[np.inf, 0, 1]]])),
        (H, "1 of 32"),
    ),
    ("NaN beam directions", dict(directions=np.full((32, 3), np.nan)), (H, "beam directions")),
    ("zero beam directions", dict(directions=np.zeros((32, 3))), (H, "zero vectors")),
    ("zero beams", dict(directions=np.zeros((0, 3))), (H, "0 beams")),
    ("1x1 images", dict(ranges=RANGES[:1], directions=DIRS[:1]), (H, "1 range bins x 1 beams")),
    ("one range bin", dict(ranges=RANGES[:1]), (H, "1 range bins")),
    ("navigation 100 s after the pings", dict(nav_offset_ns=100 * 10**9), (H, "posed")),
    ("navigation 1 h before the pings", dict(nav_offset_ns=-3600 * 10**9), (H, "posed")),
    ("all sonar messages at one timestamp", dict(same_time=True), (H, "same time")),
    (
        "1 km navigation jump",
        dict(nav=_nav(_add((slice(200, None), 0), 1000.0))),
        (NAV, "jumps", "t_ns="),
    ),
    ("100 m navigation jump", dict(nav=_nav(_add((slice(150, None), 1), 100.0))), (NAV, "jumps")),
    (
        "all-zero quaternions",
        dict(nav=_nav(_set(slice(None), 0.0), quats=True)),
        (NAV, "quaternion"),
    ),
    (
        "all-NaN quaternions",
        dict(nav=_nav(_set(slice(None), np.nan), quats=True)),
        (NAV, "none of"),
    ),
    ("all-NaN positions", dict(nav=_nav(_set(slice(None), np.nan))), (NAV, "none of")),
    ("all-inf positions", dict(nav=_nav(_set(slice(None), np.inf))), (NAV, "none of")),
]
EXIT_CODES = [
    Case("exit codes", name, _rec("h.mcap", **kw), check=names("h.mcap", *parts))
    for name, kw, parts in REFUSED
]


def _keyframes_at_least(
    n: int, warning: str | None
) -> Callable[[Path, subprocess.CompletedProcess[str]], str | None]:
    """The run committed a keyframes table of at least `n` rows and warned `warning`."""

    def check(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
        import pyarrow.parquet as pq

        tables = list((work / "data" / "store" / "keyframes").glob("*/keyframes.parquet"))
        rows = pq.read_metadata(tables[0]).num_rows if tables else 0
        if rows < n:
            return f"{rows} keyframes, expected at least {n}"
        if warning is not None and warning not in done.stderr:
            return f"no warning {warning!r} on stderr"
        return None

    return check


def _cut(frac: float, layout: str) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        full = work / "full.mcap"
        write_recording(full, n_pings=120, n_ranges=600, n_beams=128, layout=layout)
        data = full.read_bytes()
        (work / "cut.mcap").write_bytes(data[: int(len(data) * frac)])
        full.unlink()
        return ["run", "cut.mcap", "--until", "keyframes"]

    return build


def _dups(work: Path) -> list[str]:
    from mcap.reader import make_reader

    from sonarmap.pipeline.formats.rosmsg import recording_writer

    write_recording(work / "a.mcap", n_pings=40)
    with (
        (work / "a.mcap").open("rb") as f,
        (work / "d.mcap").open("wb") as g,
        recording_writer(g) as w,
    ):
        for schema, channel, message in make_reader(f).iter_messages():
            assert schema is not None
            w.write_raw(channel.topic, schema.name, bytes(message.data), message.log_time)
            if channel.topic == H and message.log_time % 2_000_000_000 == 0:
                w.write_raw(channel.topic, schema.name, bytes(message.data), message.log_time)
    return ["run", "d.mcap", "--until", "keyframes"]


EMPTY_MAPS = [
    Case(
        "empty maps",
        "a third of the quaternions NaN",
        _rec(
            "q.mcap",
            ("--until", "keyframes"),
            nav=_nav(_set(slice(None, None, 3), np.nan), quats=True),
        ),
        expect_exit=(0,),
        check=_keyframes_at_least(5, "dropped 70 of 210"),
    ),
    Case(
        "empty maps",
        "a few zero quaternions",
        _rec("q.mcap", ("--until", "keyframes"), nav=_nav(_set(slice(10, 20), 0.0), quats=True)),
        expect_exit=(0,),
        check=_keyframes_at_least(5, "dropped 10 of 210"),
    ),
    Case(
        "empty maps",
        "NaN positions in a stretch",
        _rec("q.mcap", ("--until", "keyframes"), nav=_nav(_set(slice(50, 60), np.nan))),
        expect_exit=(0,),
        check=_keyframes_at_least(5, "dropped 10 of 210"),
    ),
    Case(
        "empty maps",
        "one 1 km navigation glitch",
        _rec("g.mcap", ("--until", "keyframes"), nav=_nav(_add((100, 0), 1000.0))),
        expect_exit=(0,),
        check=_keyframes_at_least(5, "dropped 1 of 210"),
    ),
    Case(
        "empty maps",
        "duplicate ping timestamps",
        _dups,
        expect_exit=(0,),
        check=_keyframes_at_least(5, "duplicate timestamps"),
    ),
    *[
        Case(
            "empty maps",
            f"sonarmap's own layout cut at {int(f * 100)} %",
            _cut(f, "recording"),
            expect_exit=(0,),
            check=_keyframes_at_least(max(1, int(f * 15) - 3), "truncated"),
        )
        for f in (0.3, 0.5, 0.8, 0.95)
    ],
    Case(
        "empty maps",
        "recorder layout cut at 80 %",
        _cut(0.8, "interleaved"),
        expect_exit=(0,),
        check=_keyframes_at_least(9, "truncated"),
    ),
]

CASES = [*RESOURCES, *EXIT_CODES, *EMPTY_MAPS]
