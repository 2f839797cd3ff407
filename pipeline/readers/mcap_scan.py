"""Lenient sequential MCAP scanning: every complete record before a cut or corruption.

A recording cut by a power loss has no summary and ends inside a record, usually inside
a compressed chunk. `scan_records` yields every Schema, Channel and Message record that
can be read, decompresses the readable prefix of a cut chunk, and reports how many bytes
at the end could not be read.
"""

from __future__ import annotations

import io
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.records import Channel, Chunk, Message, Schema

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.readers.limits import CHUNK_LIMIT_ENV, max_chunk_bytes

__all__ = ["ChunkCorrupt", "ChunkOverLimit", "ScanResult", "decompress_chunk", "scan_records"]

_OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 0x02, 0x03, 0x04, 0x05, 0x06
MAGIC = b"\x89MCAP0\r\n"


@dataclass
class ScanResult:
    """Filled in while `scan_records` runs.

    Attributes:
        size: file size [bytes].
        good_until: offset after the last complete top-level record.
        recovered: messages recovered from a cut chunk.
        complete: True when the file ended normally (footer and closing magic read).
        problem: why reading stopped before the end ("" for a plain cut).
    """

    size: int = 0
    good_until: int = 0
    recovered: int = 0
    complete: bool = False
    problem: str = ""

    @property
    def unreadable_bytes(self) -> int:
        return 0 if self.complete else self.size - self.good_until


def _inner_records(data: bytes) -> Iterator[Schema | Channel | Message]:
    """Complete records of an (uncompressed, possibly cut) chunk payload."""
    from mcap.data_stream import ReadDataStream

    pos = 0
    while pos + 9 <= len(data):
        opcode = data[pos]
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        end = pos + 9 + length
        if end > len(data):
            return
        stream = ReadDataStream(io.BytesIO(data[pos + 9 : end]))
        if opcode == _OP_SCHEMA:
            yield Schema.read(stream)
        elif opcode == _OP_CHANNEL:
            yield Channel.read(stream)
        elif opcode == _OP_MESSAGE:
            yield Message.read(stream, length)
        pos = end


def _partial_chunk(f: io.BufferedReader, offset: int) -> Iterator[Schema | Channel | Message]:
    """Records from the readable prefix of a chunk cut at the end of the file (at most
    its declared uncompressed size, itself within `max_chunk_bytes`, is decompressed)."""
    f.seek(offset)
    head = f.read(9 + 8 + 8 + 8 + 4 + 4)
    if len(head) < 41 or head[0] != _OP_CHUNK:
        return
    (declared,) = struct.unpack_from("<Q", head, 25)
    (name_len,) = struct.unpack_from("<I", head, 37)
    compression = f.read(name_len).decode(errors="replace")
    f.read(8)  # records length
    payload = f.read()
    cap = min(declared, max_chunk_bytes())
    try:
        if compression == "zstd":
            import zstandard

            with zstandard.ZstdDecompressor().stream_reader(payload) as reader:
                data = _read_upto(reader, cap)
        elif compression == "lz4":
            import lz4.frame

            data = lz4.frame.LZ4FrameDecompressor().decompress(payload, max_length=cap)
        elif compression == "":
            data = payload[:cap]
        else:
            return
    except Exception:  # a corrupt block: nothing more can be read
        return
    yield from _inner_records(data)


def _read_upto(reader: Any, n: int) -> bytes:
    """Up to n bytes from a zstd stream reader; a cut frame yields what decoded before it."""
    parts, got = [], 0
    while got < n:
        try:
            block = reader.read(min(n - got, 1 << 20))
        except Exception:  # the cut: keep what was decoded
            break
        if not block:
            break
        parts.append(block)
        got += len(block)
    return b"".join(parts)


def scan_records(path: Path, result: ScanResult) -> Iterator[Schema | Channel | Message]:
    """Yield Schema/Channel/Message records in file order, tolerating a cut end.

    Args:
        path: MCAP file.
        result: filled with the file size, the last good offset and what was recovered.
    """
    from mcap.data_stream import ReadDataStream

    result.size = size = path.stat().st_size
    with path.open("rb") as f:
        if f.read(8) != MAGIC:
            return
        result.good_until = pos = 8
        while True:
            head = f.read(9)
            if len(head) < 9:
                break
            opcode = head[0]
            (length,) = struct.unpack_from("<Q", head, 1)
            if pos + 9 + length > size:
                break
            body = f.read(length)
            stream = ReadDataStream(io.BytesIO(body))
            try:
                if opcode == _OP_CHUNK:
                    try:
                        inner = list(_inner_records(decompress_chunk(Chunk.read(stream))))
                    except ChunkOverLimit as err:
                        # Not damage to read past: the file asks for more memory than allowed.
                        raise SourceError(f"{path}: MCAP chunk at byte offset {pos} {err}") from err
                elif opcode == _OP_SCHEMA:
                    inner = [Schema.read(stream)]
                elif opcode == _OP_CHANNEL:
                    inner = [Channel.read(stream)]
                elif opcode == _OP_MESSAGE:
                    inner = [Message.read(stream, length)]
                else:
                    inner = []
            except (McapError, struct.error, ValueError, EOFError) as err:
                kind = {_OP_CHUNK: "chunk", _OP_SCHEMA: "schema", _OP_CHANNEL: "channel"}
                result.problem = f"{kind.get(opcode, 'record')} at byte offset {pos}: {err}"
                break
            pos = result.good_until = pos + 9 + length
            yield from inner
            if opcode == _OP_FOOTER:
                result.complete = f.read(8) == MAGIC
                if result.complete:
                    result.good_until = size
                return
        for rec in _partial_chunk(f, result.good_until):
            if isinstance(rec, Message):
                result.recovered += 1
            yield rec


class ChunkCorrupt(ValueError):
    """A chunk that does not decompress, or whose data fails its stored size or CRC."""


class ChunkOverLimit(ChunkCorrupt):
    """A chunk declaring more uncompressed bytes than `max_chunk_bytes` allows."""


_ONE_SHOT_MAX_BYTES = 1 << 28
"""Largest chunk decompressed in one shot (one buffer of its size, GIL released)."""


def _decompress(chunk: Chunk) -> bytes:
    # Output never exceeds the declared size plus one byte (which proves the lie), and
    # the declared size is capped first: memory follows the limit, not the payload.
    size = chunk.uncompressed_size
    limit = max_chunk_bytes()
    if size > limit:
        raise ChunkOverLimit(
            f"declares {size} bytes uncompressed, over the limit of {limit >> 20} MiB "
            f"(set {CHUNK_LIMIT_ENV} to raise it)"
        )
    try:
        if chunk.compression == "zstd":
            import zstandard

            # One shot (a third faster, and it releases the GIL) only when the frame's own
            # content size confirms the chunk's: zstandard sizes its buffer by the frame
            # header, whatever `max_output_size` says. Otherwise a capped stream.
            if 0 < size <= _ONE_SHOT_MAX_BYTES and _zstd_content_size(chunk.data) == size:
                return zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=size)
            with zstandard.ZstdDecompressor().stream_reader(bytes(chunk.data)) as reader:
                return bytes(reader.read(size + 1))
        if chunk.compression == "lz4":
            import lz4.frame

            out = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=size + 1)
            return bytes(out)
    # Decompressors raise their own types (ZstdError, RuntimeError, ...) on corrupt input.
    except Exception as err:
        raise ChunkCorrupt(f"{chunk.compression} data does not decompress ({err})") from err
    if chunk.compression == "":
        return bytes(chunk.data)
    raise ChunkCorrupt(f"unsupported chunk compression {chunk.compression!r}")


def _zstd_content_size(data: bytes) -> int:
    """The content size a zstd frame header declares (-1: none or unreadable)."""
    import zstandard

    try:
        return int(zstandard.frame_content_size(data))
    except zstandard.ZstdError:
        return -1


def decompress_chunk(chunk: Chunk) -> bytes:
    """The chunk's records, checked against its uncompressed size and CRC (when non-zero).

    Raises:
        ChunkCorrupt: the payload does not decompress, or its size or CRC is wrong.
        ChunkOverLimit: it declares more than `max_chunk_bytes()` uncompressed.
    """
    data = _decompress(chunk)
    if len(data) > chunk.uncompressed_size:
        raise ChunkCorrupt(
            f"decompresses to more than the {chunk.uncompressed_size} bytes it declares"
        )
    if len(data) != chunk.uncompressed_size:
        raise ChunkCorrupt(
            f"decompressed to {len(data)} bytes, the chunk says {chunk.uncompressed_size}"
        )
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise ChunkCorrupt(
            f"CRC mismatch (stored {chunk.uncompressed_crc:#010x}, data {zlib.crc32(data):#010x})"
        )
    return data
