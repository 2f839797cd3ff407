"""The `frames` output kind as the engine's `Codec` (`sonarmap.pipeline.formats.frames_io`
does the work).

The engine stores parquet, json and bytes itself; a graph hands it the codecs of its
other kinds. This module is what the real graph and the training graph hand over: it
imports neither numpy nor mcap until a `frames` output is written or read, so building
a graph for a cached run stays light (docs/decisions/020-cached-run-imports.md).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from sonarmap.pipeline.engine.store.codecs import Codec

if TYPE_CHECKING:
    from sonarmap.schemas.sonar import KeyframeImages

__all__ = ["FRAMES_CODECS"]


def write_frames(frames: Iterable[KeyframeImages], path: Path) -> int:
    from sonarmap.pipeline.formats.frames_io import write_frames as write

    return write(frames, path)


def read_frames(path: Path) -> Sequence[KeyframeImages]:
    from sonarmap.pipeline.formats.frames_io import read_frames as read

    return read(path)


FRAMES_CODECS = {"frames": Codec(write=write_frames, read=read_frames)}
"""Output kind -> codec, for `Graph.codecs` and readers of `frames` outputs."""
