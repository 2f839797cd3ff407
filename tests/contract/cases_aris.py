"""Hostile inputs for the other makers' readers (issue 37 items 3 and 4): ARIS files cut
short, corrupt or claiming absurd sizes; custom message definitions that are missing,
broken or huge; beam tables that do not fit; sqlite bags on write-protected storage.

ARIS files are synthesised here from the maker's header layout
(`sonarmap.pipeline.readers.aris_layout`), so the campaign needs no third-party data.
"""

from __future__ import annotations

import shutil
import sqlite3
import stat
import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np

from sonarmap.pipeline.readers.aris_layout import FILE_HEADER, FRAME_HEADER, SIGNATURE
from tests.contract.case import Case
from tests.fixtures.shared_data import SHARED_DATA

ROOT = Path(__file__).resolve().parents[2]
BEAMS, SAMPLES = 48, 200
FRAME = 1024 + BEAMS * SAMPLES


def _aris(path: Path, n_frames: int = 4, edit: Callable[[np.ndarray], None] | None = None) -> bytes:
    """A valid ARIS file of `n_frames` 48-beam frames; `edit` changes the frame headers."""
    head = np.zeros(1, FILE_HEADER)
    head["Version"], head["NumRawBeams"], head["SamplesPerChannel"] = SIGNATURE, BEAMS, SAMPLES
    frames = np.zeros(n_frames, [("h", FRAME_HEADER), ("s", np.uint8, (BEAMS * SAMPLES,))])
    h = frames["h"]
    h["FrameIndex"] = np.arange(n_frames)
    h["FrameTime"] = 1_700_000_000_000_000 + np.arange(n_frames) * 100_000
    h["Version"], h["PingMode"], h["SamplesPerBeam"] = SIGNATURE, 1, SAMPLES
    h["SamplePeriod"], h["SampleStartDelay"], h["SoundSpeed"] = 14, 4593, 1480.0
    h["ReorderedSamples"], h["TheSystemType"] = 1, 2
    frames["s"] = np.random.default_rng(0).integers(0, 255, (n_frames, BEAMS * SAMPLES))
    if edit is not None:
        edit(h)
    data = head.tobytes() + frames.tobytes()
    path.write_bytes(data)
    return data


def _cut(size: int) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        data = _aris(work / "dive.aris")
        (work / "dive.aris").write_bytes(data[:size])
        return ["topics", "dive.aris"]

    return build


def _edit(field: str, value: object, frame: int | slice = 0) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        def edit(h: np.ndarray) -> None:
            h[field][frame] = value

        _aris(work / "dive.aris", edit=edit)
        return ["topics", "dive.aris"]

    return build


def _sparse_claim(work: Path) -> list[str]:
    """A valid first frame, then 4 GiB of holes: frame 1 has no signature."""
    data = _aris(work / "big.aris", n_frames=1)
    with (work / "big.aris").open("r+b") as f:
        f.truncate(len(data) + (4 << 30))
    return ["topics", "big.aris"]


def _run_aris(work: Path) -> list[str]:
    _aris(work / "dive.aris")
    return ["run", "dive.aris", "--until", "keyframes"]


def _convert_with(table: str) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        _aris(work / "dive.aris")
        if table.endswith(".csv"):
            (work / table).write_text("\n".join(str(a) for a in range(BEAMS - 1)) + "\n")
        return [
            "convert",
            "dive.aris",
            "-o",
            "out.mcap",
            "--set",
            f"keyframes.horizontal_sonar={table}",
        ]

    return build


def _converted_with_the_tables_fan(
    work: Path, proc: subprocess.CompletedProcess[str]
) -> str | None:
    return None if (work / "out.mcap").is_file() else "no out.mcap written"


def _msg(text: str | None, rel: str, size: int = 0) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        _sqlite_bag(work)
        path = work / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        if text is None and rel.endswith("/"):
            path.mkdir()
        elif text is not None:
            path.write_text(text + "#" * size)
        return ["topics", "bag", "--msg", rel]

    return build


def _sqlite_bag(work: Path) -> Path:
    bag = work / "bag"
    shutil.copytree(
        SHARED_DATA / "bags" / "ros2" / "talker_sqlite3",
        bag,
        ignore=shutil.ignore_patterns("*-shm", "*-wal"),
    )
    for p in bag.iterdir():
        p.chmod(0o644)
    return bag


def _protected_bag(work: Path) -> list[str]:
    bag = _sqlite_bag(work)
    for p in [*bag.iterdir(), bag]:
        p.chmod(stat.S_IMODE(p.stat().st_mode) & ~0o222)
    return ["topics", "bag"]


def _nothing_written(work: Path, proc: subprocess.CompletedProcess[str]) -> str | None:
    names = sorted(p.name for p in (work / "bag").iterdir())
    (work / "bag").chmod(0o755)
    return None if names == ["metadata.yaml", "talker.db3"] else f"bag now holds {names}"


def _wal_left(work: Path) -> list[str]:
    bag = _sqlite_bag(work)
    db = sqlite3.connect(bag / "talker.db3")
    db.execute("PRAGMA wal_autocheckpoint=0")
    db.execute(
        "INSERT INTO messages (topic_id, timestamp, data) SELECT topic_id, timestamp + 1, data FROM messages LIMIT 1"
    )
    db.commit()
    # Leave the log behind as a crashed writer would: copy it before the close folds it in.
    shutil.copy(bag / "talker.db3-wal", work / "wal")
    db.close()
    shutil.copy(work / "wal", bag / "talker.db3-wal")
    return ["topics", "bag"]


def _wal_named(work: Path, proc: subprocess.CompletedProcess[str]) -> str | None:
    return (
        None
        if "talker.db3-wal" in proc.stderr and "not read" in proc.stderr
        else "no warning about the write-ahead log"
    )


_STAMPED = "std_msgs/Header header\nuint32 ping_id\nuint8[] data\n"

CASES = [
    # ARIS files cut short: nothing readable is refused; a cut last frame is named, not fatal.
    Case("exit codes", "aris: header only (1024 bytes)", _cut(1024)),
    Case("exit codes", "aris: 100 bytes", _cut(100)),
    Case("exit codes", "aris: cut inside the first frame", _cut(1024 + FRAME - 1)),
    Case("exit codes", "aris: cut inside the first frame header", _cut(1024 + 500)),
    Case(
        "data loss",
        "aris: cut inside frame 3 (3 frames read, the cut named)",
        _cut(1024 + 3 * FRAME + 77),
        expect_exit=(0,),
    ),
    # Corrupt headers: refused naming frame and byte offset.
    Case("exit codes", "aris: frame 2 without its signature", _edit("Version", 0, 2)),
    Case("exit codes", "aris: PingMode 0", _edit("PingMode", 0)),
    Case("exit codes", "aris: PingMode 99", _edit("PingMode", 99)),
    Case("exit codes", "aris: PingMode changes in frame 3", _edit("PingMode", 3, 3)),
    Case(
        "exit codes",
        "aris: samples not reordered (raw device capture)",
        _edit("ReorderedSamples", 0, slice(None)),
    ),
    Case("exit codes", "aris: sound speed NaN in frame 1", _edit("SoundSpeed", np.nan, 1)),
    Case("exit codes", "aris: sound speed 0", _edit("SoundSpeed", 0.0)),
    Case("exit codes", "aris: sound speed 1e30", _edit("SoundSpeed", 1e30)),
    Case("exit codes", "aris: sample period 0", _edit("SamplePeriod", 0)),
    Case("exit codes", "aris: SamplesPerBeam changes in frame 2", _edit("SamplesPerBeam", 100, 2)),
    Case("exit codes", "aris: run on one sonar refused in one line", _run_aris),
    # Absurd sizes: refused before anything is sized from them.
    Case("resources", "aris: SamplesPerBeam 2^32-1", _edit("SamplesPerBeam", 0xFFFFFFFF)),
    Case(
        "resources",
        "aris: SamplesPerBeam 16384 (frame past the end)",
        _edit("SamplesPerBeam", 16384),
    ),
    Case("resources", "aris: 4 GiB sparse file after one frame", _sparse_claim),
    # Beam tables that do not fit, on `convert` (which decodes every ARIS frame).
    Case("exit codes", "beam table: unknown preset", _convert_with("no-such-sonar")),
    Case("exit codes", "beam table: 47 angles for 48 beams", _convert_with("short.csv")),
    Case(
        "trust",
        "beam table: the ARIS preset by name",
        _convert_with("aris1800-48"),
        expect_exit=(0,),
        check=_converted_with_the_tables_fan,
    ),
    # Custom message definitions.
    Case("exit codes", "--msg: file missing", _msg(None, "pkg/msg/Missing.msg")),
    Case("exit codes", "--msg: not a .msg or .idl", _msg(_STAMPED, "defs.txt")),
    Case("exit codes", "--msg: not at <package>/msg/", _msg(_STAMPED, "Ping.msg")),
    Case("exit codes", "--msg: unparsable", _msg("float64[ x", "pkg/msg/Broken.msg")),
    Case("exit codes", "--msg: misspelt field type", _msg("flaot64 depth", "pkg/msg/Typo.msg")),
    Case(
        "exit codes",
        "--msg: unknown nested type",
        _msg("other_pkg/Thing thing", "pkg/msg/Nested.msg"),
    ),
    Case("exit codes", "--msg: broken .idl", _msg("module x { struct", "defs/x.idl")),
    Case("resources", "--msg: 2 MB definition", _msg(_STAMPED, "pkg/msg/Huge.msg", size=2 << 20)),
    Case("exit codes", "--msg: a directory", _msg(None, "pkg/msg/Dir.msg/")),
    # Reading never writes beside a recording.
    Case(
        "trust",
        "sqlite bag on write-protected storage: nothing written",
        _protected_bag,
        expect_exit=(0,),
        check=_nothing_written,
    ),
    Case(
        "trust",
        "sqlite bag with a leftover write-ahead log: named",
        _wal_left,
        expect_exit=(0,),
        check=_wal_named,
    ),
]
