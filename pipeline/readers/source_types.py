"""What every recording backend shares: topic descriptions, the Source protocol, index checks.

A leaf below `sonarmap.pipeline.readers.sources` (which opens a file with the right backend) and
every backend, so neither imports the other's module."""

from __future__ import annotations

import logging
from collections.abc import Collection, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:  # numpy loads when a recording is read, not when one is fingerprinted
    import numpy as np

log = logging.getLogger(__name__)

__all__ = ["Source", "TimeIndexedSource", "TopicInfo", "check_counts"]


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a recording.

    Attributes:
        topic: topic name.
        msgtype: ROS 2 style type name ("pkg/msg/Type").
        count: messages actually present (read from the data or a verified index).
        first_ns, last_ns: first/last log time [ns], None when the topic is empty.
        indexed_count: the count the file's own index/metadata claims (None if it has none).
    """

    topic: str
    msgtype: str
    count: int
    first_ns: int | None
    last_ns: int | None
    indexed_count: int | None = None

    @property
    def rate_hz(self) -> float:
        """Mean message rate over the topic's time span (0 for fewer than two messages)."""
        if self.count < 2 or self.first_ns is None or self.last_ns is None:
            return 0.0
        span = (self.last_ns - self.first_ns) * 1e-9
        return (self.count - 1) / span if span > 0 else 0.0


class Source(Protocol):
    """What every reader backend offers."""

    path: Path
    kind: str
    warnings: list[str]

    def topics(self) -> list[TopicInfo]:
        """Every topic with its type and counts, sorted by name."""
        ...

    def times(self, topic: str) -> np.ndarray:
        """(n,) int64 log times [ns] of the topic's messages, ascending."""
        ...

    def messages(
        self, topics: Sequence[str], times: Collection[int] | None = None
    ) -> Iterator[tuple[str, int, Any]]:
        """Deserialised `(topic, t_ns, message)` in log-time order.

        Args:
            topics: topics to read.
            times: when given, only messages with these log times are deserialised.
        """
        ...

    def attachments(self) -> dict[str, bytes]:
        """Named attachments (e.g. "scene.ply"); empty when the format has none."""
        ...


def check_counts(path: Path, topics: list[TopicInfo], warnings: list[str]) -> None:
    """Warn about topics whose index claims more (or fewer) messages than are present."""
    for info in topics:
        if info.indexed_count is not None and info.indexed_count != info.count:
            msg = (
                f"{path}: topic {info.topic} has {info.count} readable messages but the "
                f"bag's index says {info.indexed_count}"
            )
            warnings.append(msg)
            log.warning(msg)


class TimeIndexedSource:
    """Base of the backends that learn every topic's message times when they open a file."""

    warnings: list[str]

    def _set_topics(
        self,
        path: Path,
        times: dict[str, np.ndarray],
        msgtypes: dict[str, str],
        indexed: dict[str, int] | None,
    ) -> None:
        """Store the topics' (n,) ascending log times [ns]; warn where the index disagrees."""
        self._times = times
        self._topics = [
            TopicInfo(
                topic=name,
                msgtype=msgtypes[name],
                count=len(t),
                first_ns=int(t[0]) if len(t) else None,
                last_ns=int(t[-1]) if len(t) else None,
                indexed_count=None if indexed is None else indexed.get(name, 0),
            )
            for name, t in sorted(times.items())
        ]
        check_counts(path, self._topics, self.warnings)

    def topics(self) -> list[TopicInfo]:
        return list(self._topics)

    def times(self, topic: str) -> np.ndarray:
        import numpy as np

        return self._times.get(topic, np.zeros(0, np.int64))
