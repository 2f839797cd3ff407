"""Chunks of submap frames mapped in worker processes (`submaps.workers`).

The workers get the mapper and the recording pickled once, as their start-up payload
(a `SourceRecording` pickles as its path, options and topic roles, and reopens), and map
chunks of `FRAMES_PER_CHUNK` frames; the chunks come back in order
(`sonarmap.stages.kernels.parallel.ordered_map`), so the stage writes the same bytes for any number of
workers. Spawned workers import the caller's main module again: a script that runs the
pipeline with workers > 1 needs the usual `if __name__ == "__main__":` guard.
"""

from __future__ import annotations

import logging
import pickle
from collections.abc import Iterator

from sonarmap.schemas.recording import Recording
from sonarmap.stages.kernels.parallel import available_cores, ordered_map, release_memory
from sonarmap.stages.submaps.mapping import FRAMES_PER_CHUNK, FrameMapper, MappedChunk

__all__ = ["mapped_chunks", "worker_count"]

logger = logging.getLogger(__name__)


def mapped_chunks(
    mapper: FrameMapper, rec: Recording, chunks: list[tuple[int, int]], workers: int | None
) -> Iterator[MappedChunk]:
    """The chunks mapped in order: here, or in worker processes when that pays.

    Workers get the mapper and the recording pickled once, as their start-up payload;
    a recording that does not pickle (one opened by a test's stage graph) is mapped
    here.
    """
    n = worker_count(workers, chunks[-1][1] if chunks else 0)
    payload = None
    if n > 1:
        try:
            payload = pickle.dumps((mapper, rec), protocol=pickle.HIGHEST_PROTOCOL)
        except (pickle.PicklingError, TypeError, AttributeError) as err:
            logger.info("submaps: %s does not pickle (%s); one process", rec.name, err)
    if payload is None:
        yield from ordered_map(lambda c: mapper.map_chunk(rec, *c), chunks, 1)
        return
    yield from ordered_map(_worker_chunk, chunks, n, _start_worker, (payload,))


def worker_count(workers: int | None, frames: int) -> int:
    """Processes that map `frames` submap frames under `submaps.workers` (1: this one)."""
    chunks = -(-frames // FRAMES_PER_CHUNK)
    return max(1, min(available_cores() if workers is None else workers, chunks))


_WORKER: tuple[FrameMapper, Recording] | None = None
"""A worker process's mapper and recording (`_start_worker`)."""


def _start_worker(payload: bytes) -> None:
    global _WORKER
    # Our own payload, pickled by the parent for its workers: never a user's file.
    _WORKER = pickle.loads(payload)


def _worker_chunk(chunk: tuple[int, int]) -> MappedChunk:
    assert _WORKER is not None, "worker not initialised"
    mapper, rec = _WORKER
    mapped = mapper.map_chunk(rec, *chunk)
    release_memory()  # a worker's peak is its largest chunk, not its share of the frames
    return mapped
