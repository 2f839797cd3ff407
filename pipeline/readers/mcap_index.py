"""Where each channel's messages are in an indexed MCAP file, from its message indexes.

The message indexes follow each chunk back to back; they are read one block per chunk
and parsed into per-channel arrays (time, chunk number, offset inside the chunk), so a
reader fetches a message by decompressing only the chunk that holds it.
"""

from __future__ import annotations

import struct
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np
from mcap.records import ChunkIndex

from sonarmap.pipeline.readers.mcap_integrity import IndexCorrupt, message_index_entries

__all__ = ["Locations", "index_block", "index_locations"]

_OP_MESSAGE_INDEX = 0x07
_MAX_INDEX_BLOCK_SLACK = 1 << 20


@dataclass(frozen=True)
class Locations:
    """Where one channel's messages are: (n,) log times [ns] ascending, chunk numbers
    (into the file's chunks sorted by offset) and byte offsets inside the uncompressed chunk."""

    t: np.ndarray
    chunk: np.ndarray
    offset: np.ndarray


def index_block(f: BinaryIO, chunk: ChunkIndex, size: int) -> tuple[int, bytes]:
    """(start offset, bytes) of the span holding all of a chunk's message indexes: one
    read per chunk instead of one per channel (they follow the chunk back to back)."""
    offsets = chunk.message_index_offsets.values()
    start, end = min(offsets), max(offsets) + 9
    # A damaged length must not size the read; a record past the block is read on its own.
    if end <= start + chunk.message_index_length <= end + _MAX_INDEX_BLOCK_SLACK:
        end = start + chunk.message_index_length
    f.seek(start)
    return start, f.read(min(end, size) - start)


def index_locations(path: Path, chunks: list[ChunkIndex]) -> dict[int, Locations]:
    """Per channel, every message's time and place, from the chunks' message indexes."""
    parts: dict[int, list[tuple[np.ndarray, int]]] = defaultdict(list)
    size = path.stat().st_size
    with path.open("rb") as f:
        for k, chunk in enumerate(chunks):
            if chunk.chunk_start_offset + chunk.chunk_length > size:
                # Sorted last, its messages would seem recorded after every other's.
                raise IndexCorrupt(
                    f"the chunk index at byte offset {chunk.chunk_start_offset} points past "
                    "the end of the file"
                )
            if not chunk.message_index_offsets:
                continue
            start, block = index_block(f, chunk, size)
            for cid, offset in chunk.message_index_offsets.items():
                at = offset - start
                head = block[at : at + 9]
                if len(head) < 9 or head[0] != _OP_MESSAGE_INDEX:
                    raise IndexCorrupt(f"no message index at byte offset {offset}")
                (length,) = struct.unpack_from("<Q", head, 1)
                if offset + 9 + length > size:
                    raise IndexCorrupt(f"message index at byte offset {offset} ends past the file")
                if at + 9 + length > len(block):
                    f.seek(offset + 9)
                    body = f.read(length)
                else:
                    body = block[at + 9 : at + 9 + length]
                entries = message_index_entries(body, offset, cid, chunk)
                parts[cid].append((entries, k))
    out = {}
    for cid, items in parts.items():
        t = np.concatenate([e[:, 0] for e, _ in items]).astype(np.int64)
        chunk_no = np.concatenate([np.full(len(e), k, np.int64) for e, k in items])
        off = np.concatenate([e[:, 1] for e, _ in items]).astype(np.int64)
        order = np.lexsort((off, chunk_no, t))
        out[cid] = Locations(t[order], chunk_no[order], off[order])
    return out
