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

import errno
import itertools
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from sonarmap.pipeline.engine.errors import OutputError, SourceError
from sonarmap.pipeline.readers.limits import max_chunk_bytes

__all__ = [
    "MAGIC",
    "TAIL",
    "Growth",
    "McapSnapshot",
    "check_followable",
    "check_mcap_start",
    "mcap_closed",
]

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
_CHECK_BYTES = 4096
"""Bytes compared at the start of the copied part and at its end, at each look."""
_DISK_FULL = (errno.ENOSPC, errno.EDQUOT)


def check_followable(path: Path) -> None:
    """SourceError unless `path` is an MCAP file (`check_mcap_start`) or a bag directory
    without sqlite3 files (what a recorder writing MCAP storage makes): empty, or holding
    an MCAP file or a metadata.yaml."""
    if path.is_file():
        check_mcap_start(path)
    elif not path.exists():
        raise SourceError(f"{path}: no such file or directory")
    elif not path.is_dir():
        raise SourceError(f"{path}: not a regular file or a directory (a FIFO, a device?)")
    elif others := sorted(p.name for p in path.glob("*.db3")):
        raise SourceError(
            f"{path}: sqlite3 storage ({others[0]}): `follow` reads a bag recorded "
            "with MCAP storage (`ros2 bag record -s mcap`); `run` it once it is closed"
        )
    else:
        _check_bag_directory(path)


def _check_bag_directory(path: Path) -> None:
    """SourceError when a directory holds files but none a recorder writing MCAP storage
    makes (`*.mcap`, `metadata.yaml`): a folder of ROS 1 bags or of anything else would
    otherwise be waited on forever. An empty folder passes: the recorder may have just
    made it. Each MCAP file there must start as one (`check_mcap_start`)."""
    names = list(itertools.islice(path.iterdir(), 10_000))
    mcaps = [p for p in names if p.suffix == ".mcap" and p.is_file()]
    for mcap in mcaps:
        check_mcap_start(mcap)
    if names and not mcaps and not (path / "metadata.yaml").exists():
        bags = [p.name for p in names if p.suffix == ".bag"]
        hint = (
            f" ({bags[0]} is a ROS 1 bag: `sonarmap convert` it, then `run` the MCAP)"
            if bags
            else ""
        )
        raise SourceError(
            f"{path}: not a rosbag2 directory being recorded: none of its {len(names)}"
            f" entries is an .mcap file or metadata.yaml{hint}"
        )


def check_mcap_start(path: Path) -> None:
    """SourceError unless `path` starts as an MCAP file does (or holds less than the magic:
    a recorder that has just opened it)."""
    with path.open("rb") as f:
        head = f.read(len(MAGIC))
    if head != MAGIC[: len(head)]:  # not even the start of the magic: it never will be one
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
        self._identity: tuple[int, int] | None = None  # (device, inode) of the file followed
        self.waiting = ""
        """Why a source that stopped growing is not closed yet ("" when nothing to say)."""

    @property
    def size(self) -> int:
        """Bytes of the source copied into the snapshot (header and complete records)."""
        return self.copied_until

    def update(self) -> Growth:
        """Copy the complete records added to the source since the last call.

        Raises:
            SourceError: the source is not an MCAP file, declares an impossible record, or
                is shorter than what was copied already.
        """
        try:
            f = self.source.open("rb")
        except FileNotFoundError as err:
            raise SourceError(f"{self.source}: no such file") from err
        with f:
            stat = os.fstat(f.fileno())
            if self._identity not in (None, (stat.st_dev, stat.st_ino)):
                raise SourceError(
                    f"{self.source}: replaced by another file while followed (moved or "
                    "copied over): what was mapped is another recording's; `run` each"
                )
            self._identity = (stat.st_dev, stat.st_ino)
            size = f.seek(0, 2)
            if size < self.copied_until:
                raise SourceError(
                    f"{self.source}: shrank from {self.copied_until} to {size} bytes while"
                    " followed (truncated or written again): what was mapped may be gone;"
                    " `run` it once it is written"
                )
            if self.copied_until > 0:
                self._check_unchanged(f)
            if self.copied_until == 0:
                check_mcap_start(self.source)
                if size < len(MAGIC):
                    return Growth(0, 0, None, False)
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.path.write_bytes(MAGIC + TAIL)
                self.copied_until = len(MAGIC)
            try:
                new_bytes, records = self._copy(f, size)
            except OSError as err:
                if err.errno not in _DISK_FULL:
                    raise
                raise OutputError(
                    f"{self.path.parent}: {err.strerror} (follow's copy of the recording, up to"
                    " 3x its size with the preview's: set TMPDIR to a folder on a larger disk)"
                ) from err
        closed = self.data_ended and mcap_closed(self.source)
        self.waiting = (
            f"{self.source}: its data section ended but no footer follows yet"
            if self.data_ended and not closed
            else ""
        )
        return Growth(new_bytes, records, self.last_log_time_ns, closed)

    def _check_unchanged(self, f: object) -> None:
        """Refuse a source whose bytes already copied changed: a recording copied over the
        followed one (`cp` keeps the inode) or a recorder restarted on its name, whose
        records would otherwise be appended to the first one's as if one recording."""
        import io

        assert isinstance(f, io.BufferedReader)
        n = min(_CHECK_BYTES, self.copied_until)
        with self.path.open("rb") as copy:
            for start in (0, self.copied_until - n):
                f.seek(start)
                copy.seek(start)
                if f.read(n) != copy.read(n):
                    raise SourceError(
                        f"{self.source}: written again while followed (its bytes before"
                        f" offset {start + n} changed: another recording copied over it, or"
                        " a recorder restarted on its name): what was mapped is another"
                        " recording's; `run` each once it is written"
                    )

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
