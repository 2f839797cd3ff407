"""rosbag2 sqlite3 storage, read directly with the standard library.

rosbags 0.11.9 silently yields no messages from some official sqlite3 bags (the QoS
text in metadata.yaml differs from the database's), so the database tables are read
here and the counts are checked against metadata.yaml.

Reading never writes beside the recording: each database is opened read-only and
immutable (`?mode=ro&immutable=1`), so sqlite neither creates the `-shm`/`-wal` files a
WAL-mode database otherwise gets on open nor needs a writable directory (archive shares,
mounted disk images).

Messages are stored in the order they arrived (rising row id, split files in order) and
sorted by time when read, so a recorder clock set back shows in the row order: such
messages are dropped with a warning (`clock.backwards`).
"""

from __future__ import annotations

import logging
import sqlite3
from collections.abc import Collection, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.readers.clock import backwards
from sonarmap.pipeline.readers.source_types import TimeIndexedSource
from sonarmap.pipeline.readers.typestores import Ros2Decoder

log = logging.getLogger(__name__)

__all__ = ["SqliteSource"]


class SqliteSource(TimeIndexedSource):
    """A rosbag2 bag in sqlite3 storage (one or more .db3 files in time order)."""

    kind = "rosbag2-sqlite3"

    def __init__(
        self,
        path: Path,
        files: Sequence[Path],
        indexed: dict[str, int] | None,
        extra_types: dict[str, Any] | None = None,
    ) -> None:
        self.path = path
        self.warnings: list[str] = []
        self._files = list(files)
        # sqlite bags carry no message definitions: custom types come from the user's files.
        self._decoder = Ros2Decoder(extra_types=extra_types)
        self._types: dict[str, str] = {}
        # (file number, row id, time) of each topic's messages, in the order recorded.
        rows: dict[str, list[np.ndarray]] = {}
        for k, f in enumerate(self._files):
            self._check_wal(f)
            with self._connect(f) as db:
                for name, typ in db.execute("SELECT name, type FROM topics"):
                    self._types.setdefault(name, typ)
                    rows.setdefault(name, []).append(self._rows(db, k, name))
        self._behind: set[tuple[int, int]] = set()
        sorted_times = {k: self._drop_backwards(k, np.concatenate(v)) for k, v in rows.items()}
        if indexed is not None:
            # What metadata.yaml claims, less what a clock set back drops (warned already).
            for name, t in sorted_times.items():
                dropped = sum(len(r) for r in rows[name]) - len(t)
                if name in indexed:
                    indexed = {**indexed, name: indexed[name] - dropped}
        self._set_topics(path, sorted_times, self._types, indexed)

    @staticmethod
    def _rows(db: sqlite3.Connection, k: int, name: str) -> np.ndarray:
        """(n, 3) file number, row id and time of a topic's messages, in row order (read
        in batches into arrays: a row tuple each would be ~100 bytes a message)."""
        cur = db.execute(
            "SELECT m.id, m.timestamp FROM messages m JOIN topics t ON m.topic_id = t.id "
            "WHERE t.name = ? ORDER BY m.id",
            (name,),
        )
        parts = [np.zeros((0, 2), np.int64)]
        while batch := cur.fetchmany(100_000):
            parts.append(np.asarray(batch, np.int64).reshape(-1, 2))
        both = np.concatenate(parts)
        return np.column_stack([np.full(len(both), k, np.int64), both])

    def _drop_backwards(self, topic: str, rows: np.ndarray) -> np.ndarray:
        """The topic's ascending times, less the messages recorded behind an earlier time
        (remembered by file and row id, so that `messages` skips them too)."""
        found = backwards(rows[:, 2])
        if found is None:
            return np.sort(rows[:, 2])
        self._behind.update((int(f), int(i)) for f, i in rows[found.behind, :2])
        line = found.warning(f"{self.path}: {topic}")
        self.warnings.append(line)
        log.warning(line)
        return np.sort(rows[~found.behind, 2])

    def _check_wal(self, f: Path) -> None:
        """An immutable open does not read a write-ahead log: say so when one holds data."""
        wal = f.with_name(f.name + "-wal")
        if wal.is_file() and wal.stat().st_size > 0:
            self.warnings.append(
                f"{wal}: {wal.stat().st_size} bytes of write-ahead log not checkpointed into "
                f"{f.name} are not read (sonarmap never writes beside a recording; open the bag "
                "once with sqlite3 where it is writable to fold them in)"
            )

    @staticmethod
    def _connect(f: Path) -> sqlite3.Connection:
        try:
            # A file: URI so that '?', '#' and '%' in the path are percent-encoded.
            uri = f"{f.resolve().as_uri()}?mode=ro&immutable=1"
            db = sqlite3.connect(uri, uri=True)
            db.execute("SELECT count(*) FROM messages").fetchone()
        except sqlite3.DatabaseError as err:
            raise SourceError(f"{f}: not a readable rosbag2 sqlite3 database ({err})") from err
        return db

    def messages(
        self, topics: Sequence[str], times: Collection[int] | None = None
    ) -> Iterator[tuple[str, int, Any]]:
        wanted = None if times is None else set(times)
        marks = ",".join("?" * len(topics))
        for k, f in enumerate(self._files):
            with self._connect(f) as db:
                cur = db.execute(
                    "SELECT t.name, m.timestamp, m.data, m.id FROM messages m JOIN topics t "
                    f"ON m.topic_id = t.id WHERE t.name IN ({marks}) ORDER BY m.timestamp",
                    tuple(topics),
                )
                for name, t, data, row in cur:
                    if (wanted is not None and t not in wanted) or (k, row) in self._behind:
                        continue
                    msg = self._decoder.decode(data, self._types[name], name)
                    if msg is not None:
                        yield name, int(t), msg

    def attachments(self) -> dict[str, bytes]:
        return {}
