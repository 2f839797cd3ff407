"""ROS 1 bags (plain, bz2 or lz4 chunks) through rosbags' AnyReader.

Message type names are rosbags' ROS 2 style ("sonar_oculus/msg/OculusPing"); the bag's
embedded definitions are used to deserialise, so custom types need no registration.

A recorder stores messages in the order they arrived (chunks in file order, messages at
rising offsets within a chunk) while the index is sorted by time, so a recorder clock set
back shows in the file order: such messages of the streams sonarmap maps from (sonar,
navigation, DVL, IMU, depth) are dropped with a warning (`clock.backwards`). Other topics
are left as the index has them: the rosbag API lets a script write any topic with times
out of order (as in rosbags' unsorted-chunks example), and such a topic is listed whole.
"""

from __future__ import annotations

import bz2
import logging
import struct
from collections import defaultdict
from collections.abc import Callable, Collection, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.formats.rosmsg import ros1_typestore
from sonarmap.pipeline.readers.clock import backwards
from sonarmap.pipeline.readers.depth import FLUID_PRESSURE_TYPE
from sonarmap.pipeline.readers.dvl import TWIST_TYPES
from sonarmap.pipeline.readers.limits import CHUNK_LIMIT_ENV, max_chunk_bytes
from sonarmap.pipeline.readers.navigation import NAV_TYPES
from sonarmap.pipeline.readers.roles import IMU_TYPE
from sonarmap.pipeline.readers.sonar_decode import IMAGE_SONAR_TYPES, SONAR_TYPES
from sonarmap.pipeline.readers.source_types import TimeIndexedSource

log = logging.getLogger(__name__)

__all__ = ["Ros1Source"]


def _capped(compression: str, size: int, path: str, pos: int) -> Callable[[bytes], bytes]:
    """A chunk decompressor whose output stops one byte past the declared size."""

    def decompress(data: bytes) -> bytes:
        try:
            if compression == "bz2":
                out = bz2.BZ2Decompressor().decompress(data, max_length=size + 1)
            elif compression == "lz4":
                import lz4.frame

                out = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
            else:
                out = bytes(data)
        except Exception as err:  # bz2/lz4 raise OSError, RuntimeError, ... on bad data
            raise SourceError(
                f"{path}: corrupt {compression} bag chunk at byte offset {pos} ({err})"
            ) from err
        if len(out) != size:
            raise SourceError(
                f"{path}: bag chunk at byte offset {pos} decompresses to "
                f"{'more than' if len(out) > size else len(out)} bytes, it declares {size}"
            )
        return bytes(out)

    return decompress


MAPPED_TYPES = frozenset(
    (*SONAR_TYPES, *IMAGE_SONAR_TYPES, *NAV_TYPES, *TWIST_TYPES, IMU_TYPE, FLUID_PRESSURE_TYPE)
)
"""Message types of the streams a map is made from: their clocks are checked."""


class Ros1Source(TimeIndexedSource):
    """A ROS 1 bag file."""

    kind = "rosbag1"

    def __init__(self, path: Path) -> None:
        from rosbags.highlevel import AnyReader

        self.path = path
        self.warnings: list[str] = []
        try:
            self._reader = AnyReader([path], default_typestore=ros1_typestore())
            self._reader.open()
        except Exception as err:
            why = str(err) or type(err).__name__
            raise SourceError(
                f"{path}: cannot read ROS 1 bag ({why}); its index is missing or damaged "
                "(a bag cut before its index was written): reindex it (rosbag reindex) first"
            ) from err
        self._bound_chunks()
        self._conns = defaultdict(list)
        tables = {}  # (time, chunk position, offset) of each connection's index entries
        for conn in self._reader.connections:
            self._conns[conn.topic].append(conn)
            tables[conn.id] = self._entry_table(conn)
            self._refuse_repeated_entries(conn, tables[conn.id])
        # What the index claims, less what a clock set back drops (warned on its own).
        counts = {t: sum(c.msgcount for c in conns) for t, conns in self._conns.items()}
        for topic, conns in self._conns.items():
            if conns[0].msgtype in MAPPED_TYPES:
                counts[topic] -= self._drop_backwards(topic, conns, tables)
        self._set_topics(
            path,
            {topic: self._index_times(conns) for topic, conns in self._conns.items()},
            {topic: conns[0].msgtype for topic, conns in self._conns.items()},
            counts,
        )

    def _entry_table(self, conn: Any) -> np.ndarray:
        """(n, 3) int64 time, chunk position and offset of the connection's index entries."""
        entries = self._reader.readers[0].indexes[conn.id]
        return np.column_stack(
            [np.fromiter((e[j] for e in entries), np.int64, len(entries)) for j in range(3)]
        ).reshape(-1, 3)

    def _refuse_repeated_entries(self, conn: Any, table: np.ndarray) -> None:
        """A SourceError when the index lists one message of `conn` twice (`table`: its
        `_entry_table`): chunk infos that point at the wrong chunk (one chunk read twice,
        another lost), not a recording."""
        unique, first, counts = np.unique(table, axis=0, return_index=True, return_counts=True)
        if len(unique) < len(table):
            pos = int(table[first[np.argmax(counts > 1)], 1])
            raise SourceError(
                f"{self.path}: the bag's index lists a {conn.topic} message twice (chunk at "
                f"byte offset {pos}): its chunk infos are damaged; reindex it (rosbag reindex)"
            )

    def _drop_backwards(self, topic: str, conns: list[Any], tables: dict[int, np.ndarray]) -> int:
        """Drop from the index the messages of `topic` recorded behind an earlier time
        (file order: chunk position, then offset in the chunk); how many were dropped.
        `tables`: each connection's `_entry_table`."""
        bag: Any = self._reader.readers[0]
        lists = [bag.indexes[c.id] for c in conns]
        if sum(len(x) for x in lists) < 2:
            return 0
        # (time, chunk position, offset) of every message, connection after connection.
        table = np.concatenate([tables[c.id] for c in conns])
        order = np.lexsort((table[:, 2], table[:, 1]))
        found = backwards(table[order, 0])
        if found is None:
            return 0
        drop = np.zeros(len(table), bool)
        drop[order[found.behind]] = True
        start = 0
        for c, x in zip(conns, lists, strict=True):
            gone = drop[start : start + len(x)]
            start += len(x)
            # Still sorted by time: rosbags merges the connections' lists by time.
            bag.indexes[c.id] = [e for e, g in zip(x, gone.tolist(), strict=True) if not g]
        line = found.warning(f"{self.path}: {topic}")
        self.warnings.append(line)
        log.warning(line)
        return int(drop.sum())

    def _bound_chunks(self) -> None:
        """Give every chunk a decompressor capped at the size its header declares, and
        refuse a declared size over `max_chunk_bytes` (rosbags decompresses unbounded)."""
        from rosbags.rosbag1.reader import Chunk, Header, RecordType

        bag: Any = self._reader.readers[0]
        limit = max_chunk_bytes()
        for pos, chunk in list(getattr(bag, "chunks", {}).items()):
            try:
                bag.bio.seek(pos)
                header = Header.read(bag.bio, RecordType.CHUNK)
                compression, size = header.get_string("compression"), header.get_uint32("size")
            except Exception as err:
                raise SourceError(f"{self.path}: corrupt bag chunk at byte offset {pos}") from err
            if size > limit:
                raise SourceError(
                    f"{self.path}: bag chunk at byte offset {pos} declares {size} bytes "
                    f"uncompressed, over the limit of {limit >> 20} MiB "
                    f"(set {CHUNK_LIMIT_ENV} to raise it)"
                )
            bag.chunks[pos] = Chunk(
                chunk.datasize, chunk.datapos, _capped(compression, size, f"{self.path}", pos)
            )

    def _index_times(self, conns: list[Any]) -> np.ndarray:
        """Message times from the bag's index (no chunk is decompressed)."""
        bag: Any = self._reader.readers[0]
        parts = [np.fromiter((entry.time for entry in bag.indexes[c.id]), np.int64) for c in conns]
        return np.sort(np.concatenate(parts)) if parts else np.zeros(0, np.int64)

    def messages(
        self, topics: Sequence[str], times: Collection[int] | None = None
    ) -> Iterator[tuple[str, int, Any]]:
        """As `Source.messages`; an index that points at no message (a damaged bag) or a
        message its definition does not describe is a SourceError naming it."""
        from rosbags.rosbag1 import ReaderError

        conns = [c for t in topics for c in self._conns.get(t, [])]
        if not conns:
            return
        windows = [(None, None)] if times is None else [(t, t + 1) for t in sorted(set(times))]
        try:
            for start, stop in windows:
                for conn, t, raw in self._reader.messages(
                    connections=conns, start=start, stop=stop
                ):
                    yield conn.topic, t, self._decode(raw, conn, t)
        except (ReaderError, AssertionError, IndexError, struct.error) as err:
            # rosbags asserts on a message header its index did not point at
            raise SourceError(
                f"{self.path}: the bag's index points at no message of "
                f"{', '.join(sorted({c.topic for c in conns}))} "
                f"({type(err).__name__}{': ' + str(err) if str(err) else ''}); "
                "reindex it (rosbag reindex)"
            ) from err

    def _decode(self, raw: bytes, conn: Any, t_ns: int) -> Any:
        try:
            return self._reader.deserialize(raw, conn.msgtype)
        except Exception as err:  # rosbags raises several kinds on data it cannot parse
            raise SourceError(
                f"{self.path}: {conn.topic}: the {conn.msgtype} message at t_ns={t_ns} does "
                f"not match the definition it is decoded with ({err})"
            ) from err

    def attachments(self) -> dict[str, bytes]:
        return {}
