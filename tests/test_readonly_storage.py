"""Reading never writes beside a recording: every real file in ../shared/data is listed
from a write-protected copy, and nothing in that directory changes.

Root ignores permission bits, so besides `chmod -R a-w` the test checks what a read-only
mount would enforce: no file appears, disappears or changes size or mtime."""

from __future__ import annotations

import os
import shutil
import sqlite3
import stat
from pathlib import Path

import pytest
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.readers import open_source

# Every recording sonarmap reads among the third-party files, and the exit code of
# `topics` on it (an empty file is refused, exit 2).
RECORDINGS = {
    "bags/ros1/example.bag": 0,
    "bags/ros1/example-bz2.bag": 0,
    "bags/ros1/example-lz4.bag": 0,
    "bags/ros1/example-unsorted-chunks.bag": 0,
    "bags/ros1/no-messages.bag": 0,
    "bags/ros1/empty-file.bag": 2,
    "bags/ros2/talker_mcap": 0,
    "bags/ros2/talker_sqlite3": 0,
    "bags/ros2/wbag_split": 0,
    "bags/ros2/cdr_test": 0,
    "bags/ros2/only_topics.mcap": 0,
    "bags/ros2/topics_and_services.mcap": 0,
    "oculus/one_ping_8bit.raw": 0,
    "aris/sample.aris": 0,
}


_SQLITE_SIDE_FILES = shutil.ignore_patterns("*-shm", "*-wal")


def _snapshot(root: Path) -> dict[str, tuple[int, int, int]]:
    """Every entry under root: (size, mtime_ns, mode)."""
    out = {}
    for p in sorted(root.rglob("*")):
        st = p.lstat()
        out[str(p.relative_to(root))] = (st.st_size, st.st_mtime_ns, stat.S_IMODE(st.st_mode))
    return out


def _protect(root: Path) -> None:
    for p in [root, *root.rglob("*")]:
        p.chmod(stat.S_IMODE(p.stat().st_mode) & ~0o222)


def _unprotect(root: Path) -> None:
    for p in [root, *root.rglob("*")]:
        p.chmod(stat.S_IMODE(p.stat().st_mode) | 0o200)


@pytest.fixture
def archive(shared_data: Path, tmp_path: Path):
    """A write-protected copy of the third-party recordings."""
    root = tmp_path / "archive"
    for folder in ("bags", "oculus", "aris"):
        # Leave out -shm/-wal files an older reader may have written beside the originals.
        shutil.copytree(shared_data / folder, root / folder, ignore=_SQLITE_SIDE_FILES)
    _protect(root)
    yield root
    _unprotect(root)  # so pytest can remove tmp_path


def test_topics_on_a_write_protected_archive_writes_nothing(archive: Path) -> None:
    before = _snapshot(archive)
    assert all(mode & 0o222 == 0 for _, _, mode in before.values())
    for rel, expected in RECORDINGS.items():
        res = CliRunner().invoke(app, ["topics", str(archive / rel), "--json"])
        assert res.exit_code == expected, (rel, res.output)
        assert "Traceback" not in res.output
    assert _snapshot(archive) == before
    if os.geteuid() != 0:
        return  # the permission bits were enforced above
    # As root the bits are not enforced: the snapshot comparison above is the check.


def test_wal_mode_sqlite_bag_gets_no_shm_or_wal_files(archive: Path) -> None:
    bag = archive / "bags" / "ros2" / "talker_sqlite3"
    db = bag / "talker.db3"
    assert db.read_bytes()[18:20] == b"\x02\x02"  # WAL mode: sqlite would make -shm/-wal
    src = open_source(bag)
    assert {t.topic: t.count for t in src.topics()}["/topic"] == 10
    assert len(list(src.messages(["/topic"]))) == 10
    assert sorted(p.name for p in bag.iterdir()) == ["metadata.yaml", "talker.db3"]


def test_a_leftover_write_ahead_log_is_named_not_silently_ignored(
    shared_data: Path, tmp_path: Path
) -> None:
    bag = tmp_path / "bag"
    shutil.copytree(
        shared_data / "bags" / "ros2" / "talker_sqlite3", bag, ignore=_SQLITE_SIDE_FILES
    )
    db = bag / "talker.db3"
    db.chmod(0o644)
    # A writer that crashed leaves committed rows in talker.db3-wal (no checkpoint).
    keep = sqlite3.connect(db)
    keep.execute("PRAGMA wal_autocheckpoint=0")
    keep.execute(
        "INSERT INTO messages (topic_id, timestamp, data) SELECT topic_id, timestamp + 1, data FROM messages LIMIT 1"
    )
    keep.commit()
    assert (bag / "talker.db3-wal").stat().st_size > 0
    src = open_source(bag)
    assert any("talker.db3-wal" in w and "not read" in w for w in src.warnings)
    keep.close()


def test_paths_with_uri_characters_open(shared_data: Path, tmp_path: Path) -> None:
    bag = tmp_path / "dive #3 ?50% done"
    shutil.copytree(
        shared_data / "bags" / "ros2" / "talker_sqlite3", bag, ignore=_SQLITE_SIDE_FILES
    )
    assert {t.topic: t.count for t in open_source(bag).topics()}["/rosout"] == 10
