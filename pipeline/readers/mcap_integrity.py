"""Integrity checks of an indexed MCAP file's summary and message indexes.

The summary (channels, chunk indexes) carries a CRC in the footer; the message indexes
in the data section carry none, so each is checked against the chunk it describes. A
file that fails either check is read sequentially instead (`mcap_scan`), where every
chunk's CRC is verified as it is decompressed.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
from mcap.records import ChunkIndex

__all__ = [
    "IndexCorrupt",
    "closed_data_end",
    "message_index_entries",
    "refuse_damage",
    "summary_crc_problem",
    "unclosed",
]

_FOOTER_SIZE = 1 + 8 + 8 + 8 + 4
_MAGIC_SIZE = 8
MAGIC = b"\x89MCAP0\r\n"
_OP_FOOTER, _OP_MESSAGE_INDEX = 0x02, 0x07


class IndexCorrupt(ValueError):
    """A message index that cannot describe the chunk it belongs to."""


def _footer(path: Path) -> tuple[int, bytes] | None:
    """The footer record's offset and its bytes with the trailing magic after them (None:
    the file is too short to hold them)."""
    footer = path.stat().st_size - _MAGIC_SIZE - _FOOTER_SIZE
    if footer < _MAGIC_SIZE:
        return None
    with path.open("rb") as f:
        f.seek(footer)
        return footer, f.read(_FOOTER_SIZE + _MAGIC_SIZE)


def summary_crc_problem(path: Path) -> str | None:
    """Why the summary section fails its footer CRC (None when it passes, has no CRC, or
    the file has no readable footer: the caller's summary reader reports that)."""
    found = _footer(path)
    if found is None:
        return None
    footer, tail = found
    opcode, _, summary_start, _, summary_crc = struct.unpack_from("<BQQQI", tail)
    if opcode != _OP_FOOTER or summary_crc == 0:
        return None
    start = summary_start or footer
    if not _MAGIC_SIZE <= start <= footer:
        return f"the footer's summary offset {summary_start} is outside the file"
    with path.open("rb") as f:
        f.seek(start)
        actual = zlib.crc32(f.read(footer + _FOOTER_SIZE - 4 - start))
    if actual != summary_crc:
        return (
            f"the summary section at byte offset {start} fails its CRC "
            f"(stored {summary_crc:#010x}, data {actual:#010x})"
        )
    return None


def closed_data_end(path: Path) -> int | None:
    """Where a closed file's data section ends (its summary's offset, or its footer's when
    it has no summary), when it ends with a footer and the magic as a writer that closed it
    leaves them; None for a file cut before that (a recorder that lost power)."""
    found = _footer(path)
    if found is None:
        return None
    footer, tail = found
    opcode, length, summary_start = struct.unpack_from("<BQQ", tail)
    if opcode != _OP_FOOTER or length != 20 or not tail.endswith(b"\x89MCAP0\r\n"):
        return None
    return summary_start if _MAGIC_SIZE <= summary_start <= footer else footer


def refuse_damage(path: Path, good_until: int, problem: str | None) -> None:
    """A SourceError when a file read sequentially stops at `good_until` before the end of
    its data though the writer closed it (`closed_data_end`): the bytes it cannot read are
    damage, not a cut, and what follows them is not lost to a power cut but unread; refused,
    as a corrupt chunk is. A file cut short (no footer) passes: the caller warns."""
    from sonarmap.pipeline.engine.errors import SourceError

    end = closed_data_end(path)
    if end is not None and good_until < end:
        raise SourceError(
            f"{path}: corrupt MCAP: unreadable at byte offset {good_until}, before the end "
            f"of its data at {end}, though the file was closed"
            + (f" ({problem})" if problem else "")
        )


def message_index_entries(
    body: bytes, offset: int, channel_id: int, chunk: ChunkIndex
) -> np.ndarray:
    """(n, 2) uint64 (log time [ns], offset in the uncompressed chunk) of one message index.

    Args:
        body: the MessageIndex record after its opcode and length.
        offset: the record's byte offset in the file (for messages).
        channel_id: the channel the chunk index says this record indexes.
        chunk: the chunk index entry the record belongs to.

    Raises:
        IndexCorrupt: the record is not this channel's, or an entry lies outside the chunk.
    """
    where = f"message index at byte offset {offset}"
    if len(body) < 6:
        raise IndexCorrupt(f"{where}: record too short")
    (cid, n_bytes) = struct.unpack_from("<HI", body, 0)
    if cid != channel_id or n_bytes % 16 or 6 + n_bytes > len(body):
        raise IndexCorrupt(f"{where}: not the index of channel {channel_id}")
    entries = np.frombuffer(body, "<u8", n_bytes // 8, 6).reshape(-1, 2)
    t, off = entries[:, 0], entries[:, 1]
    if np.any(off >= chunk.uncompressed_size) or np.any(
        (t < chunk.message_start_time) | (t > chunk.message_end_time)
    ):
        raise IndexCorrupt(f"{where}: entries outside the chunk at {chunk.chunk_start_offset}")
    return entries


def unclosed(path: Path, messages: int) -> str | None:
    """The warning for a file read to its last whole record that no writer closed (it does
    not end with the MCAP magic), or None when it ends as a closed file does."""
    with path.open("rb") as f:
        size = f.seek(0, 2)
        f.seek(max(0, size - len(MAGIC)))
        if f.read() == MAGIC:
            return None
    return (
        f"{path}: not closed (no MCAP footer): its recorder was still writing it, or stopped"
        f" without closing it; the {messages} messages written so far are mapped"
    )
