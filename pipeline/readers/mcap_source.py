"""ROS 2 MCAP files (one file, or the split files of a rosbag2 directory).

Indexed files are read through their summary: message times come from the message
indexes (no decompression) and wanted messages are fetched by time window. A file
without a summary (a recording cut by a power loss) is scanned sequentially with
`mcap_scan`, which keeps every complete message and reports the unreadable tail.
"""

from __future__ import annotations

import logging
import struct
from collections import OrderedDict, defaultdict
from collections.abc import Collection, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Message, Schema
from mcap.summary import Summary

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.readers.clock import backwards
from sonarmap.pipeline.readers.mcap_attachments import read_attachments
from sonarmap.pipeline.readers.mcap_index import Locations, index_locations
from sonarmap.pipeline.readers.mcap_integrity import (
    IndexCorrupt,
    refuse_damage,
    summary_crc_problem,
    unclosed,
)
from sonarmap.pipeline.readers.mcap_scan import (
    ChunkCorrupt,
    ScanResult,
    decompress_chunk,
    scan_records,
)
from sonarmap.pipeline.readers.source_types import TopicInfo, check_counts
from sonarmap.pipeline.readers.typestores import Ros2Decoder

__all__ = ["McapSource"]

log = logging.getLogger(__name__)


_OP_MESSAGE, _OP_CHUNK = 0x05, 0x06
_CACHED_CHUNKS = 8
_PREFETCH_CHUNKS = 2
# Decompressed chunks held at once [declared bytes]: with chunks up to the reader's limit
# (`limits.max_chunk_bytes`), memory stays bounded whatever the chunks declare.
_CACHE_BYTES = 256 << 20
_PREFETCH_MAX_BYTES = 32 << 20
_MIN_INDEXED_BYTES = 8 + 29 + 8
"""Leading magic, footer record (opcode, length, two offsets, CRC) and trailing magic."""


def _summary(path: Path) -> tuple[Summary | None, str | None]:
    """The summary section, or None and why it cannot be used (None: the file has none)."""
    if path.stat().st_size < _MIN_INDEXED_BYTES:  # no room for a footer to seek back to
        return None, None
    try:
        with path.open("rb") as f:
            problem = summary_crc_problem(path)
            if problem is not None:
                return None, problem
            return SeekingReader(f).get_summary(), None
    except (McapError, struct.error, ValueError, EOFError, OverflowError):
        return None, None


class _McapFile:
    """One MCAP file: channels, schemas, per-channel times, and how to fetch messages."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.summary, problem = _summary(path)
        # Kept when the messages are read sequentially (an unchunked file has no chunk
        # indexes): the attachments are still where the summary says.
        self.attachment_indexes = list(self.summary.attachment_indexes) if self.summary else []
        self.scan = ScanResult()
        self.index_problem: str | None = None
        if problem is not None:
            self.index_problem = f"{path}: {problem}; read sequentially instead"
        self.channels: dict[int, Channel] = {}
        self.schemas: dict[int, Schema] = {}
        self.times: dict[int, np.ndarray] = {}
        self.behind: dict[int, set[int]] = {}
        self.clock_warnings: list[str] = []
        if self.summary is not None and self.summary.chunk_indexes:
            self.channels = dict(self.summary.channels)
            self.schemas = dict(self.summary.schemas)
            self.chunks = sorted(self.summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
            try:
                self.locations = index_locations(path, self.chunks)
            except (IndexCorrupt, struct.error, ValueError) as err:
                self.index_problem = f"{path}: {err}; read sequentially instead"
                self.summary = None
        if self.summary is not None and self.summary.chunk_indexes:
            self.times = {cid: loc.t for cid, loc in self.locations.items()}
            self._cache: OrderedDict[int, Future[bytes]] = OrderedDict()
            self._pool: ThreadPoolExecutor | None = None
            counts = (
                self.summary.statistics.channel_message_counts if self.summary.statistics else {}
            )
            bad = [
                f"{ch.topic} ({counts.get(c, 0)} counted, {len(self.times.get(c, ()))} indexed)"
                for c, ch in sorted(self.channels.items())
                if counts and counts.get(c, 0) != len(self.times.get(c, ()))
            ]
            if bad:
                self.index_problem = (
                    f"{path}: the MCAP statistics and message indexes disagree for "
                    f"{', '.join(bad)}; read sequentially instead"
                )
                self.summary = None
        if self.summary is None or not self.summary.chunk_indexes:
            self.summary = None
            self._scan_index()
        else:
            self._drop_backwards_indexed()

    def _drop_backwards_indexed(self) -> None:
        """Index entries recorded behind an earlier time of their channel are dropped
        (`clock.backwards`, by the file order of chunk and offset), with a warning."""
        for cid, loc in list(self.locations.items()):
            order = np.lexsort((loc.offset, loc.chunk))
            found = backwards(loc.t[order])
            if found is None:
                continue
            keep = np.ones(len(loc.t), bool)
            keep[order[found.behind]] = False
            self.locations[cid] = Locations(loc.t[keep], loc.chunk[keep], loc.offset[keep])
            self.times[cid] = loc.t[keep]
            self.clock_warnings.append(found.warning(f"{self.path}: {self.channels[cid].topic}"))

    def _scan_index(self) -> None:
        self.channels, self.schemas = {}, {}
        times: dict[int, list[int]] = defaultdict(list)
        for rec in scan_records(self.path, self.scan):
            if isinstance(rec, Message):
                times[rec.channel_id].append(rec.log_time)
            elif isinstance(rec, Channel):
                self.channels[rec.id] = rec
            elif isinstance(rec, Schema):
                self.schemas[rec.id] = rec
        self.times = {}
        for c, t_list in times.items():
            t = np.asarray(t_list, dtype=np.int64)
            found = backwards(t)
            if found is not None:
                self.behind[c] = set(np.flatnonzero(found.behind).tolist())
                name = self.channels[c].topic if c in self.channels else f"channel {c}"
                self.clock_warnings.append(found.warning(f"{self.path}: {name}"))
                t = t[~found.behind]
            self.times[c] = np.sort(t)

    def raw(
        self, channel_ids: set[int], times: Collection[int] | None
    ) -> Iterator[tuple[int, int, bytes]]:
        """(channel id, log time, CDR bytes) of the wanted messages (log-time order when
        indexed, file order when scanned)."""
        if self.summary is not None:
            yield from self._indexed(channel_ids, times)
            return
        wanted = None if times is None else set(times)
        seen: dict[int, int] = defaultdict(int)
        for rec in scan_records(self.path, ScanResult()):
            if not isinstance(rec, Message) or rec.channel_id not in channel_ids:
                continue
            k = seen[rec.channel_id]
            seen[rec.channel_id] = k + 1
            if k in self.behind.get(rec.channel_id, ()):
                continue  # recorded behind an earlier time: dropped when opened
            if wanted is None or rec.log_time in wanted:
                yield rec.channel_id, rec.log_time, rec.data

    def _chunk(self, k: int, ahead: Sequence[int] = ()) -> bytes:
        """Uncompressed chunk k, the last `_CACHED_CHUNKS` kept: the two sonars' streams
        (`SourceRecording.pings`) read in step, each holding its ping's chunks and the
        next one's; both sonars often share a chunk; the navigation may have its own.

        A worker thread reads the chunks `ahead` (the caller's next ones) meanwhile:
        file reads, one-shot zstd and CRC release the GIL, so they overlap the caller.
        """
        for j in ahead:
            self._submit(j, prefetch=True)
        future = self._submit(k)
        assert future is not None
        return future.result()

    def _submit(self, k: int, prefetch: bool = False) -> Future[bytes] | None:
        if k in self._cache:
            self._cache.move_to_end(k)
            return self._cache[k]
        size = self.chunks[k].uncompressed_size
        if prefetch and size > _PREFETCH_MAX_BYTES:
            return None  # large chunks are read when needed, one at a time
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="mcap-chunks")
        future = self._pool.submit(self._read_chunk_at, k)
        self._cache[k] = future
        # Bounded in count and in declared bytes (the newest entry always stays).
        held = sum(self.chunks[j].uncompressed_size for j in self._cache)
        while len(self._cache) > 1 and (len(self._cache) > _CACHED_CHUNKS or held > _CACHE_BYTES):
            j, _ = self._cache.popitem(last=False)
            held -= self.chunks[j].uncompressed_size
        return future

    def _read_chunk_at(self, k: int) -> bytes:
        with self.path.open("rb") as f:
            return self._read_chunk(f, k)

    def _read_chunk(self, f: BinaryIO, k: int) -> bytes:
        """Chunk k decompressed and checked (SourceError naming its offset when corrupt)."""
        offset = self.chunks[k].chunk_start_offset
        f.seek(offset)
        try:
            if f.read(1) != bytes([_OP_CHUNK]):
                raise ChunkCorrupt("no chunk record there")
            f.seek(8, 1)
            return decompress_chunk(Chunk.read(ReadDataStream(f)))
        except (ChunkCorrupt, McapError, struct.error, ValueError, EOFError) as err:
            raise SourceError(
                f"{self.path}: corrupt MCAP chunk at byte offset {offset}: {err}"
            ) from err

    def verify(self) -> None:
        """Decompress every chunk and check its CRC (SourceError on the first bad one)."""
        if self.summary is None:
            return  # scanned: every chunk was checked while scanning
        with self.path.open("rb") as f:
            for k in range(len(self.chunks)):
                self._read_chunk(f, k)

    def _message(self, data: bytes, off: int, cid: int, t: int, k: int) -> bytes:
        """The CDR payload of the message record an index entry points at."""
        end = off + 9 + 22
        if end <= len(data):
            opcode, length, channel, _, log_time = struct.unpack_from("<BQHIQ", data, off)
            ok = opcode == _OP_MESSAGE and channel == cid and log_time == t
            if ok and off + 9 + length <= len(data):
                return data[end : off + 9 + length]
        raise SourceError(
            f"{self.path}: the message index of chunk at byte offset "
            f"{self.chunks[k].chunk_start_offset} points at no message of its channel "
            f"(offset {off} in the chunk)"
        )

    def _indexed(
        self, channel_ids: set[int], times: Collection[int] | None
    ) -> Iterator[tuple[int, int, bytes]]:
        """Fetch messages by their index entries; only chunks holding them are decompressed."""
        picks = []
        wanted = None if times is None else np.fromiter(times, np.int64)
        for cid in sorted(channel_ids):
            loc = self.locations.get(cid)
            if loc is None:
                continue
            keep = slice(None) if wanted is None else np.isin(loc.t, wanted)
            picks.append(
                np.column_stack(
                    [loc.t[keep], loc.chunk[keep], loc.offset[keep], np.full(len(loc.t[keep]), cid)]
                )
            )
        if not picks:
            return
        rows = np.concatenate(picks)
        rows = rows[np.lexsort((rows[:, 2], rows[:, 1], rows[:, 0]))]
        if len(rows) == 0:
            return
        # The distinct chunks in the order they are needed, and each row's place in it.
        new_chunk = np.r_[True, rows[1:, 1] != rows[:-1, 1]]
        sequence = rows[new_chunk, 1].tolist()
        place = (np.cumsum(new_chunk) - 1).tolist()
        for (t, k, off, cid), p in zip(rows.tolist(), place, strict=True):
            ahead = sequence[p + 1 : p + 1 + _PREFETCH_CHUNKS]
            yield cid, t, self._message(self._chunk(k, ahead), off, cid, t, k)


class McapSource:
    """A ROS 2 recording stored as one or more MCAP files (in time order)."""

    kind = "mcap"

    def __init__(
        self, path: Path, files: Sequence[Path], indexed: dict[str, int] | None = None
    ) -> None:
        self.path = path
        self.warnings: list[str] = []
        try:
            self._files = [_McapFile(f) for f in files]
        except OSError as err:
            raise SourceError(f"{path}: cannot read ({err})") from err
        for f in self._files:
            for problem in ([f.index_problem] if f.index_problem else []) + f.clock_warnings:
                self.warnings.append(problem)
                log.warning(problem)
            if f.summary is None and f.scan.unreadable_bytes:
                refuse_damage(f.path, f.scan.good_until, f.scan.problem)
            if f.summary is None and f.scan.unreadable_bytes:
                msg = (
                    f"{f.path}: truncated or corrupt MCAP: {f.scan.unreadable_bytes} of "
                    f"{f.scan.size} bytes after offset {f.scan.good_until} were unreadable "
                    f"({f.scan.recovered} messages recovered from a cut chunk)"
                    + (f"; {f.scan.problem}" if f.scan.problem else "")
                )
                self.warnings.append(msg)
                log.warning(msg)
            elif f.summary is None and not f.channels and f.scan.good_until <= 8:
                raise SourceError(f"{f.path}: not a readable MCAP file")
            elif (  # ends on a whole record, so nothing is unreadable: was it closed?
                f.summary is None
                and f.index_problem is None
                and (msg := unclosed(f.path, sum(map(len, f.times.values()))))
            ):
                self.warnings.append(msg)
                log.warning(msg)
        # A chunk's CRC is checked when it is decompressed, so nothing is computed from a
        # corrupt chunk; `verify` (run by `sonarmap topics`) checks the chunks no run needs.
        self._decoder = Ros2Decoder(self._schema_texts())
        self._topics = self._topic_infos(indexed)
        check_counts(path, self._topics, self.warnings)

    def verify(self) -> None:
        """Decompress every chunk of every file and check its CRC (SourceError naming the
        file and the chunk's offset on the first bad one)."""
        for f in self._files:
            f.verify()

    def _schema_texts(self) -> dict[str, tuple[str, str]]:
        texts: dict[str, tuple[str, str]] = {}
        for f in self._files:
            for s in f.schemas.values():
                texts[s.name] = (s.encoding, s.data.decode(errors="replace"))
        return texts

    def _msgtype(self, f: _McapFile, ch: Channel) -> str:
        schema = f.schemas.get(ch.schema_id)
        return schema.name if schema is not None else ""

    def _topic_infos(self, indexed: dict[str, int] | None) -> list[TopicInfo]:
        types: dict[str, str] = {}
        times: dict[str, list[np.ndarray]] = defaultdict(list)
        for f in self._files:
            for cid, ch in f.channels.items():
                types.setdefault(ch.topic, self._msgtype(f, ch))
                times[ch.topic].append(f.times.get(cid, np.zeros(0, np.int64)))
        infos = []
        for topic in sorted(types):
            t = np.concatenate(times[topic])
            infos.append(
                TopicInfo(
                    topic=topic,
                    msgtype=types[topic],
                    count=len(t),
                    first_ns=int(t.min()) if len(t) else None,
                    last_ns=int(t.max()) if len(t) else None,
                    indexed_count=None if indexed is None else indexed.get(topic, 0),
                )
            )
        return infos

    def topics(self) -> list[TopicInfo]:
        return list(self._topics)

    def times(self, topic: str) -> np.ndarray:
        parts = [
            f.times.get(cid, np.zeros(0, np.int64))
            for f in self._files
            for cid, ch in f.channels.items()
            if ch.topic == topic
        ]
        return np.sort(np.concatenate(parts)) if parts else np.zeros(0, np.int64)

    def messages(
        self, topics: Sequence[str], times: Collection[int] | None = None
    ) -> Iterator[tuple[str, int, Any]]:
        for f in self._files:
            ids = {cid for cid, ch in f.channels.items() if ch.topic in topics}
            if not ids:
                continue
            for cid, t, data in f.raw(ids, times):
                ch = f.channels[cid]
                msg = self._decoder.decode(data, self._msgtype(f, ch), ch.topic)
                if msg is not None:
                    yield ch.topic, t, msg

    def attachments(self) -> dict[str, bytes]:
        out: dict[str, bytes] = {}
        for f in self._files:
            out.update(read_attachments(f.path, f.attachment_indexes))
        return out
