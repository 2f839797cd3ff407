"""ROS 1 bags (plain, bz2 or lz4 chunks) through rosbags' AnyReader.

Message type names are rosbags' ROS 2 style ("sonar_oculus/msg/OculusPing"); the bag's
embedded definitions are used to deserialise, so custom types need no registration.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Collection, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.engine.errors import SourceError
from pipeline.formats.rosmsg import ros1_typestore
from pipeline.readers.source_types import TimeIndexedSource

__all__ = ["Ros1Source"]


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
            raise SourceError(
                f"{path}: cannot read ROS 1 bag ({err}); a bag cut before its index was "
                "written must be reindexed (rosbag reindex) first"
            ) from err
        self._conns = defaultdict(list)
        for conn in self._reader.connections:
            self._conns[conn.topic].append(conn)
        self._set_topics(
            path,
            {topic: self._index_times(conns) for topic, conns in self._conns.items()},
            {topic: conns[0].msgtype for topic, conns in self._conns.items()},
            {topic: sum(c.msgcount for c in conns) for topic, conns in self._conns.items()},
        )

    def _index_times(self, conns: list[Any]) -> np.ndarray:
        """Message times from the bag's index (no chunk is decompressed)."""
        bag: Any = self._reader.readers[0]
        parts = [np.fromiter((entry.time for entry in bag.indexes[c.id]), np.int64) for c in conns]
        return np.sort(np.concatenate(parts)) if parts else np.zeros(0, np.int64)

    def messages(
        self, topics: Sequence[str], times: Collection[int] | None = None
    ) -> Iterator[tuple[str, int, Any]]:
        conns = [c for t in topics for c in self._conns.get(t, [])]
        if not conns:
            return
        if times is None:
            for conn, t, raw in self._reader.messages(connections=conns):
                yield conn.topic, t, self._reader.deserialize(raw, conn.msgtype)
            return
        for t in sorted(set(times)):
            for conn, tm, raw in self._reader.messages(connections=conns, start=t, stop=t + 1):
                yield conn.topic, tm, self._reader.deserialize(raw, conn.msgtype)

    def attachments(self) -> dict[str, bytes]:
        return {}
