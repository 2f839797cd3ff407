"""An MCAP file's attachments (the simulator's `scene.ply`), by its summary's attachment
indexes (a file cut before its summary has none: attachments are written at its end).

An unchunked file, or one whose message indexes fail their checks, is read sequentially
for its messages; its summary's attachment indexes still say where the attachments are.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from pathlib import Path

from mcap.exceptions import McapError
from mcap.records import Attachment, AttachmentIndex
from mcap.stream_reader import StreamReader

from sonarmap.pipeline.engine.errors import SourceError

__all__ = ["read_attachments"]


def read_attachments(path: Path, indexes: Sequence[AttachmentIndex]) -> dict[str, bytes]:
    """{name: data} of the attachments `indexes` point at (a SourceError naming the file
    when one is not there)."""
    out: dict[str, bytes] = {}
    try:
        with path.open("rb") as fh:
            for index in indexes:
                fh.seek(index.offset)
                att = next(StreamReader(fh, skip_magic=True).records)
                if not isinstance(att, Attachment):
                    raise McapError(f"no attachment at byte offset {index.offset}")
                out[att.name] = bytes(att.data)
    except (McapError, StopIteration, struct.error, ValueError, EOFError) as err:
        raise SourceError(f"{path}: corrupt MCAP attachment ({err})") from err
    return out
