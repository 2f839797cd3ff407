"""Results of one function over many items, computed in worker processes, yielded in order.

Stages whose items are independent (a simulated frame, a chunk of submap frames) use it
to spread numpy work over the cores: processes, not threads, since that work is many
small numpy and scipy calls that hold the GIL between them. Items are yielded in input
order whatever the number of workers, so the bytes a stage writes do not depend on it.

Workers are spawned, not forked: forking a process whose open3d/TBB thread pools are
running can deadlock. A worker costs about half a second to start (it imports the
stage), so callers keep one worker (in this process, no pool) for small jobs.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from concurrent.futures import Future

__all__ = ["available_cores", "ordered_map", "release_memory"]

Item = TypeVar("Item")
Result = TypeVar("Result")


def available_cores() -> int:
    """Cores this process may run on (its affinity mask where the OS has one)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def release_memory() -> None:
    """Hand freed memory back to the system (Arrow's pool and glibc's heap keep it
    otherwise), so a process's peak is its largest step, not the sum of its steps."""
    import contextlib
    import ctypes

    import pyarrow as pa

    # no gc.collect(): the arrays hold no cycles worth it, and a collection costs
    # 0.1-0.5 s once torch is loaded
    pa.default_memory_pool().release_unused()
    with contextlib.suppress(OSError, AttributeError):  # not glibc
        ctypes.CDLL("libc.so.6").malloc_trim(0)


def ordered_map(
    fn: Callable[[Item], Result],
    items: Iterable[Item],
    workers: int,
    initializer: Callable[..., None] | None = None,
    initargs: Sequence[Any] = (),
    ahead_per_worker: int = 2,
) -> Iterator[Result]:
    """`fn(item)` for each item, in order; with `workers` > 1 in that many processes.

    Args:
        fn: a module-level function (workers import it by name).
        items: its arguments; at most `workers * ahead_per_worker` are in flight, so
            results waiting to be consumed stay bounded.
        workers: processes; 1 maps `fn` here, without `initializer` (the caller holds
            the state it would set).
        initializer, initargs: run once in each worker before its first item (sets the
            worker's state, e.g. from a pickled payload).

    A consumer that stops early (an error, a closed generator) waits for the items in
    flight only; the others are cancelled.
    """
    if workers <= 1:
        yield from map(fn, items)
        return
    import multiprocessing  # here: the engine imports this module on every run, cached too
    from concurrent.futures import ProcessPoolExecutor

    pool = ProcessPoolExecutor(
        workers, multiprocessing.get_context("spawn"), initializer=initializer, initargs=initargs
    )
    try:
        pending: deque[Future[Result]] = deque()
        for item in items:
            pending.append(pool.submit(fn, item))
            if len(pending) > workers * ahead_per_worker:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
