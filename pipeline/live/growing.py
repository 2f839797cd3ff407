"""A valid, closed copy of the complete part of an MCAP file that is still being written.

A recorder appends records to its file and writes the summary, the footer and the closing
magic only when it stops; until then the last record is usually half written. `McapSnapshot`
keeps a copy holding the header and every complete data record so far, closed by a DataEnd
and a Footer whose summary offsets are 0 ("no summary section", MCAP spec): a file every
reader takes as whole (`sonarmap.pipeline.readers` scans it sequentially, without the
"cut short" warning). Each `update` reads only the bytes added since the last one: the new
complete records are appended where the old tail was, and the tail is written again.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.readers.limits import max_chunk_bytes

__all__ = ["MAGIC", "TAIL", "Growth", "McapSnapshot", "check_mcap_start", "mcap_closed"]

MAGIC = b"\x89MCAP0\r\n"
_OP_FOOTER, _OP_MESSAGE, _OP_CHUNK, _OP_DATA_END = 0x02, 0x05, 0x06, 0x0F
_HEAD = 9  # opcode (1) + record length (8)
_FOOTER_RECORD = _HEAD + 8 + 8 + 4  # summary_start, summary_offset_start, summary_crc
TAIL = (
    bytes([_OP_DATA_END])
    + struct.pack("<QI", 4, 0)  # data_section_crc 0: not computed
    + bytes([_OP_FOOTER])
    + struct.pack("<QQQI", 20, 0, 0, 0)  # no summary, no summary offsets, no CRC
    + MAGIC
)
"""What closes the snapshot: DataEnd, a Footer naming no summary, the magic."""
_READ_BYTES = 8 << 20
"""Largest piece of the source read at once (a big chunk is copied in pieces)."""


def check_mcap_start(path: Path) -> None:
    """SourceError unless `path` starts as an MCAP file does (or holds less than the magic:
    a recorder that has just opened it)."""
    with path.open("rb") as f:
        head = f.read(len(MAGIC))
    if len(head) == len(MAGIC) and head != MAGIC:
        raise SourceError(f"{path}: not an MCAP file (no MCAP magic at byte 0)")


def mcap_closed(path: Path) -> bool:
    """Whether `path` ends as a finished MCAP file does: a Footer record, then the magic."""
    try:
        with path.open("rb") as f:
            size = f.seek(0, 2)
            if size < len(MAGIC) * 2 + _FOOTER_RECORD:
                return False
            f.seek(size - len(MAGIC) - _FOOTER_RECORD)
            tail = f.read()
    except OSError:
        return False
    (length,) = struct.unpack_from("<Q", tail, 1)
    return tail[0] == _OP_FOOTER and length == 20 and tail.endswith(MAGIC)


@dataclass
class Growth:
    """What one `McapSnapshot.update` found.

    Attributes:
        new_bytes: bytes of complete records copied by this update.
        records: complete top-level records copied by this update.
        last_log_time_ns: the latest log time copied so far (chunk and message records;
            None before the first).
        closed: the source is finished (its data section ended, footer and magic written).
    """

    new_bytes: int
    records: int
    last_log_time_ns: int | None
    closed: bool


class McapSnapshot:
    """Keeps `path` a closed, summary-less MCAP copy of `source`'s complete records.

    Args:
        source: the MCAP file being written (it may not hold even its magic yet).
        path: where the snapshot is kept (overwritten).
    """

    def __init__(self, source: Path, path: Path) -> None:
        self.source = Path(source)
        self.path = Path(path)
        self.copied_until = 0  # source offset after the last copied record (0: none yet)
        self.data_ended = False
        self.last_log_time_ns: int | None = None
        # A record longer than any chunk sonarmap would decompress can only be damage:
        # waiting for it to complete would wait forever.
        self._max_record = 2 * max_chunk_bytes() + (1 << 20)

    @property
    def size(self) -> int:
        """Bytes of the source copied into the snapshot (header and complete records)."""
        return self.copied_until

    def update(self) -> Growth:
        """Copy the complete records added to the source since the last call.

        Raises:
            SourceError: the source is not an MCAP file, or declares an impossible record.
        """
        try:
            f = self.source.open("rb")
        except FileNotFoundError as err:
            raise SourceError(f"{self.source}: no such file") from err
        with f:
            size = f.seek(0, 2)
            if self.copied_until == 0:
                if size < len(MAGIC):
                    return Growth(0, 0, None, False)
                check_mcap_start(self.source)
                self.path.write_bytes(MAGIC + TAIL)
                self.copied_until = len(MAGIC)
            new_bytes, records = self._copy(f, size)
        closed = self.data_ended and mcap_closed(self.source)
        return Growth(new_bytes, records, self.last_log_time_ns, closed)

    def _copy(self, f: object, size: int) -> tuple[int, int]:
        """Append the complete records between `copied_until` and `size`, then the tail."""
        import io

        assert isinstance(f, io.BufferedReader)
        start = pos = self.copied_until
        records = 0
        f.seek(pos)
        with self.path.open("r+b") as out:
            out.seek(start)
            while not self.data_ended and pos + _HEAD <= size:
                head = f.read(_HEAD)
                opcode = head[0]
                (length,) = struct.unpack_from("<Q", head, 1)
                if length > self._max_record:
                    raise SourceError(
                        f"{self.source}: MCAP record at byte offset {pos} declares {length} "
                        f"bytes, over the limit of {self._max_record} (a damaged file)"
                    )
                end = pos + _HEAD + length
                if end > size:
                    break  # half written: read next time
                if opcode == _OP_DATA_END:
                    self.data_ended = True  # the summary follows: the snapshot has none
                    break
                out.write(head)
                first = True
                for piece in _pieces(f, length):
                    if first and opcode in (_OP_CHUNK, _OP_MESSAGE):
                        self._note_time(opcode, piece)
                    first = False
                    out.write(piece)
                pos, records = end, records + 1
            out.write(TAIL)
            out.truncate()
        self.copied_until = pos
        return pos - start, records

    def _note_time(self, opcode: int, body: bytes) -> None:
        # Chunk: message_start_time, message_end_time first; Message: channel id (2),
        # sequence (4), then log_time. Read from the record's head, nothing decompressed.
        if opcode == _OP_CHUNK and len(body) >= 16:
            (t,) = struct.unpack_from("<Q", body, 8)
        elif opcode == _OP_MESSAGE and len(body) >= 14:
            (t,) = struct.unpack_from("<Q", body, 6)
        else:
            return
        if self.last_log_time_ns is None or t > self.last_log_time_ns:
            self.last_log_time_ns = t


def _pieces(f: object, length: int) -> Iterator[bytes]:
    """`length` bytes of `f` in pieces of at most `_READ_BYTES` (memory stays bounded)."""
    while length > 0:
        piece = f.read(min(length, _READ_BYTES))  # type: ignore[attr-defined]
        if not piece:
            raise SourceError("the MCAP file shrank while it was read")
        yield piece
        length -= len(piece)
