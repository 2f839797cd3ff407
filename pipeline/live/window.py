"""The recent part of a growing MCAP recording as a small, valid MCAP file.

`follow`'s preview (`sonarmap.pipeline.live.preview`) maps each new keyframe as soon as
it is complete, so it must read the last seconds of the recording without scanning the
whole of it (a summary-less snapshot of the 8-goal marina is read in about 12 s).
`RecordWindow` walks a snapshot's complete records once, as they arrive, and notes each
data record's offset and newest log time, and the Schema and Channel records (a chunked
writer puts them inside the chunks). `write(since_ns)` then writes the MCAP header, those
Schema and Channel records, the data records holding messages logged at or after
`since_ns`, and a closing tail (`growing.TAIL`): a file the ordinary reader opens as a
whole recording of those seconds. Attachments, metadata and latched messages recorded
before the window (/tf_static) are not in it: the preview takes the mounts from the last
full update's `sensors.json`.
"""

from __future__ import annotations

import bisect
import io
import struct
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.records import Chunk

from sonarmap.pipeline.live.growing import MAGIC, TAIL
from sonarmap.pipeline.readers.mcap_scan import decompress_chunk

__all__ = ["RecordWindow"]

_OP_HEADER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 0x01, 0x03, 0x04, 0x05, 0x06
_HEAD = 9  # opcode (1) + record length (8)


def _records(data: bytes) -> list[tuple[int, int, int]]:
    """(opcode, start, end) of each record in `data` (complete records only)."""
    out, pos = [], 0
    while pos + _HEAD <= len(data):
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        end = pos + _HEAD + length
        if end > len(data):
            break
        out.append((data[pos], pos, end))
        pos = end
    return out


class RecordWindow:
    """Index of a snapshot's data records, to cut out its recent part.

    Args:
        snapshot: the snapshot file (`growing.McapSnapshot.path`): magic, then complete
            records; only its first `size` bytes are read (what `update` is told).
    """

    def __init__(self, snapshot: Path) -> None:
        self.snapshot = Path(snapshot)
        self.read_until = len(MAGIC)
        self.header = b""
        self.definitions: dict[tuple[int, int], bytes] = {}  # (opcode, id) -> record
        self._offsets: list[int] = []  # data record start offsets, ascending
        self._ends: list[int] = []
        self._t_max: list[int] = []  # running max of the newest log time up to each record

    def update(self, size: int) -> None:
        """Index the records between the last call and byte `size` of the snapshot."""
        if size <= self.read_until:
            return
        with self.snapshot.open("rb") as f:
            f.seek(self.read_until)
            data = f.read(size - self.read_until)
        base = self.read_until
        for opcode, start, end in _records(data):
            body = data[start + _HEAD : end]
            if opcode == _OP_HEADER:
                self.header = data[start:end]
            elif opcode in (_OP_SCHEMA, _OP_CHANNEL):
                self._define(data[start:end])
            elif opcode in (_OP_CHUNK, _OP_MESSAGE):
                self._index(opcode, body, base + start, base + end)
            self.read_until = base + end

    def _define(self, record: bytes) -> None:
        # Schema: id u16 first; Channel: id u16 first. Keyed by both: ids are per kind.
        (ident,) = struct.unpack_from("<H", record, _HEAD)
        self.definitions.setdefault((record[0], ident), record)

    def _index(self, opcode: int, body: bytes, start: int, end: int) -> None:
        if opcode == _OP_CHUNK:
            (t,) = struct.unpack_from("<Q", body, 8)  # message_end_time
            payload = decompress_chunk(Chunk.read(ReadDataStream(io.BytesIO(body))))
            for inner, lo, hi in _records(payload):
                if inner in (_OP_SCHEMA, _OP_CHANNEL):
                    self._define(payload[lo:hi])
        else:
            (t,) = struct.unpack_from("<Q", body, 6)  # channel (2), sequence (4), log_time
        self._offsets.append(start)
        self._ends.append(end)
        self._t_max.append(max(t, self._t_max[-1]) if self._t_max else t)

    def write(self, since_ns: int, path: Path) -> int:
        """Write the window of messages logged at or after `since_ns` to `path` (a closed
        MCAP file); the bytes of data records it holds."""
        # Records are written in about log-time order: the running max makes the first
        # record that can hold such a message a bisection away.
        i = bisect.bisect_left(self._t_max, since_ns)
        start = self._offsets[i] if i < len(self._offsets) else self.read_until
        end = self.read_until
        tmp = path.with_suffix(".tmp")
        with self.snapshot.open("rb") as f, tmp.open("wb") as out:
            out.write(MAGIC + self.header)
            for key in sorted(self.definitions):  # schemas (0x03) before channels (0x04)
                out.write(self.definitions[key])
            f.seek(start)
            out.write(f.read(end - start))
            out.write(TAIL)
        tmp.replace(path)
        return end - start
