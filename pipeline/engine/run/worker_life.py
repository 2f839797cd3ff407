"""Pool workers that die with the process that started them (a run's stage workers, a
sweep's run workers)."""

from __future__ import annotations

import ctypes
import logging
import os
import signal
import sys
import threading
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from concurrent.futures import ProcessPoolExecutor

__all__ = ["die_with_parent", "end_pool"]

log = logging.getLogger(__name__)

_PR_SET_PDEATHSIG = 1
"""prctl(2) option: the signal a process gets when its parent dies (Linux)."""


def die_with_parent(parent_pid: int, death_signal: bool = True) -> None:
    """Pool-worker initializer: the worker dies when the process that started it does.

    Without it a `kill -9` (or a SIGTERM) of a run or a sweep leaves its workers running,
    each holding a stage's or a run's memory, until their job ends, and then idle for
    good. Linux delivers SIGKILL on the parent's death; elsewhere, and as a fallback, a
    daemon thread polls the parent pid (`PARENT_POLL_S`).

    Args:
        parent_pid: the process the worker must not outlive.
        death_signal: use Linux's death signal. It fires when the *thread* that started
            the worker ends, not its process, so a pool whose workers are started from
            short-lived threads (the runner's stage threads) must poll only.
    """
    if death_signal and sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):
            log.debug("prctl(PR_SET_PDEATHSIG) unavailable", exc_info=True)
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)
    threading.Thread(
        target=_watch_parent, args=(parent_pid,), name="parent-watch", daemon=True
    ).start()


PARENT_POLL_S = 0.2
"""How often a worker that cannot have Linux's death signal looks for its parent [s]."""


def _watch_parent(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(PARENT_POLL_S)
    os._exit(1)  # from a thread: ends the whole worker, whatever it is running


def end_pool(pool: ProcessPoolExecutor) -> None:
    """Ends a pool's worker processes, whatever they are running, and drops its queue."""
    terminate_workers = getattr(pool, "terminate_workers", None)  # Python >= 3.14
    if terminate_workers is not None:
        terminate_workers()
        return
    # Before 3.14 the processes have no public handle.
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.terminate()
    for process in processes:
        process.join(timeout=5.0)
