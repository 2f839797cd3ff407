"""Corrupt variants of a small MCAP recording, by where the damage is (for the fuzz suite).

Every variant is named `category/detail`; the categories are the ones issue 23 lists:
empty, random, truncated, and bit flips in the header, a chunk's header, a chunk's
compressed payload and the index (message indexes, summary section, footer).
"""

from __future__ import annotations

import random
import struct
from dataclasses import dataclass

__all__ = ["Layout", "corrupt_variants", "layout", "without_crcs"]

_OP_HEADER, _OP_FOOTER, _OP_CHUNK, _OP_MESSAGE_INDEX, _OP_DATA_END = 0x01, 0x02, 0x06, 0x07, 0x0F


@dataclass(frozen=True)
class Layout:
    """Top-level records of an MCAP file: (opcode, offset, body length) in file order."""

    records: list[tuple[int, int, int]]
    summary_start: int
    size: int

    def of(self, opcode: int) -> list[tuple[int, int]]:
        return [(off, n) for op, off, n in self.records if op == opcode]


def layout(data: bytes) -> Layout:
    records, pos = [], 8
    while pos + 9 <= len(data) - 8:
        opcode = data[pos]
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        records.append((opcode, pos, length))
        pos += 9 + length
    (summary_start,) = struct.unpack_from("<Q", data, len(data) - 8 - 29 + 9)
    return Layout(records, summary_start, len(data))


def _flip(data: bytes, offset: int, bit: int) -> bytes:
    out = bytearray(data)
    out[offset] ^= 1 << bit
    return bytes(out)


def _chunk_header_flips(data: bytes, lay: Layout, rng: random.Random) -> dict[str, bytes]:
    # Chunk body: start time 8, end time 8, uncompressed size 8, CRC 4, compression 4+n,
    # records length 8; one flip in each field, each in another chunk.
    chunks = [off for op, off, _ in lay.records if op == _OP_CHUNK and off < lay.summary_start]
    fields = {"start_time": 9, "end_time": 17, "size": 25, "crc": 33, "name_len": 37}
    fields.update({"name": 41, "records_len": 45})
    out = {}
    for i, (name, rel) in enumerate(fields.items()):
        off = chunks[i % len(chunks)] + rel
        out[f"flip-chunk-header/{name}@{off}"] = _flip(data, off, rng.randrange(8))
    first = chunks[0]
    out["flip-chunk-header/zctd"] = data[: first + 41] + b"zctd" + data[first + 45 :]
    size_at = first + 25
    (size,) = struct.unpack_from("<Q", data, size_at)
    shrunk = bytearray(data)
    struct.pack_into("<Q", shrunk, size_at, size - 1)
    out["flip-chunk-header/size-1"] = bytes(shrunk)
    return out


def _index_flips(data: bytes, lay: Layout, rng: random.Random) -> dict[str, bytes]:
    out = {}
    for off, n in lay.of(_OP_MESSAGE_INDEX)[:: max(1, len(lay.of(_OP_MESSAGE_INDEX)) // 4)][:4]:
        at = off + 9 + rng.randrange(n)
        out[f"flip-index/message-index@{at}"] = _flip(data, at, rng.randrange(8))
    footer = lay.size - 8 - 29
    for _ in range(4):
        at = rng.randrange(lay.summary_start, footer)
        out[f"flip-index/summary@{at}"] = _flip(data, at, rng.randrange(8))
    for at in (footer + 9, footer + 25):  # summary start, summary CRC
        out[f"flip-index/footer@{at}"] = _flip(data, at, 0)
    return out


def corrupt_variants(data: bytes, seed: int = 23) -> dict[str, bytes]:
    """{category/detail: bytes} of every corruption the suite tries on `data`."""
    rng = random.Random(seed)
    lay = layout(data)
    out: dict[str, bytes] = {"empty/0-bytes": b""}
    out["random/noise-4k"] = rng.randbytes(4096)
    out["random/magic-then-noise"] = data[:8] + rng.randbytes(4096)
    out["random/magic-only"] = data[:8]
    for k in range(12):
        cut = 1 + (k * (len(data) - 2)) // 11
        out[f"truncated/at-{cut}"] = data[:cut]
    for at in (2, 8 + 9 + 2, 8 + 9 + 6):
        out[f"flip-header/@{at}"] = _flip(data, at, rng.randrange(8))
    out.update(_chunk_header_flips(data, lay, rng))
    chunks = [(off, n) for off, n in lay.of(_OP_CHUNK) if off < lay.summary_start]
    for i in range(10):
        off, n = chunks[i % len(chunks)]
        name_len = struct.unpack_from("<I", data, off + 9 + 28)[0]
        payload = off + 9 + 32 + name_len + 8
        at = rng.randrange(payload, off + 9 + n)
        out[f"flip-chunk-payload/@{at}"] = _flip(data, at, rng.randrange(8))
    out.update(_index_flips(data, lay, rng))
    return out


def without_crcs(data: bytes) -> bytes:
    """The same file with every chunk CRC and the summary CRC zeroed ("not computed")."""
    out = bytearray(data)
    lay = layout(data)
    for off, _ in lay.of(_OP_CHUNK):
        struct.pack_into("<I", out, off + 9 + 24, 0)
    struct.pack_into("<I", out, lay.size - 8 - 4, 0)
    return bytes(out)
