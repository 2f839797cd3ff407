"""Where the runner's computations run: this process, or spawned worker processes.

With `workers` = 1 every stage computes here, in order, as the serial runner always
did. With more, each stage that runs at the same time as another gets a slot: one in
this process (a thread; the stage's numpy, torch and open3d work releases the GIL, and
the runner's own thread only waits) and `workers - 1` in worker processes, spawned on
first use (a cached run starts none). A stage whose job cannot be pickled (a stage
defined in a closure) waits for the slot here. A stage off the critical path (the
figures) takes an idle worker process before the slot here: this process has the
dataset open already, and a stage that reads it would otherwise open it again in a
worker (about 1.4 s on the marina: reader imports and the file's index).

Processes are spawned, not forked, for the reason `sonarmap.stages.kernels.parallel` gives.
"""

from __future__ import annotations

import os
import pickle
import threading
from collections.abc import Callable
from concurrent.futures import Future
from types import TracebackType
from typing import TYPE_CHECKING, Any, TypeVar

from sonarmap.pipeline.engine.errors import StageFailed
from sonarmap.pipeline.engine.run.compute import ComputeJob, compute_in_worker, run_job
from sonarmap.pipeline.engine.run.worker_life import die_with_parent, end_pool
from sonarmap.stages.kernels.parallel import available_cores, release_memory

if TYPE_CHECKING:  # multiprocessing loads with the first worker process
    from concurrent.futures import ProcessPoolExecutor

__all__ = ["Slots", "default_workers"]

T = TypeVar("T")


def default_workers() -> int:
    """The cores this process may run on."""
    return available_cores()


class Slots:
    """Runs the runner's per-stage tasks, at most `workers` at a time."""

    def __init__(self, workers: int) -> None:
        self.workers = max(1, int(workers))
        self._threads: list[threading.Thread] = []
        self._pool: ProcessPoolExecutor | None = None
        self._here = threading.Lock()
        self._pool_lock = threading.Lock()
        self._pool_busy = 0
        self.verified: set[tuple[str, str, str]] = set()
        """Files hashed in this process this run (each bound file costs one hash here)."""
        self.opened: dict[str, Any] = {}
        """The dataset as opened in this process, per config section."""

    def submit(self, fn: Callable[[], T]) -> Future[T]:
        """`fn()` as a future: on a thread when several may run, else right here."""
        done: Future[T] = Future()

        def run() -> None:
            try:
                done.set_result(fn())
            except BaseException as err:
                done.set_exception(err)

        if self.workers == 1:
            run()
            return done
        # A daemon thread, not a ThreadPoolExecutor's: at an interrupt the interpreter
        # would wait for the executor's threads, and so for a stage computing here.
        thread = threading.Thread(target=run, name="sonarmap-stage", daemon=True)
        self._threads.append(thread)
        thread.start()
        return done

    def compute(self, job: ComputeJob) -> dict[str, Any]:
        """Compute one miss into `job.tmp`: a stage off the critical path in an idle
        worker process; otherwise here when the slot here is free (or the job cannot
        travel), else in a worker process."""
        if job.item.stage.off_critical_path and _picklable(job) and self._idle_process():
            return self._in_worker(job)
        here = self._here.acquire(blocking=False)
        if not here and not _picklable(job):
            self._here.acquire()
            here = True
        if here:
            try:
                return run_job(job, self.verified, self.opened)
            finally:
                release_memory()
                self._here.release()
        with self._pool_lock:
            self._pool_busy += 1
        return self._in_worker(job)

    def _idle_process(self) -> bool:
        """Claims a worker process if one is idle (released by `_in_worker`)."""
        with self._pool_lock:
            if self._pool_busy >= self.workers - 1:
                return False
            self._pool_busy += 1
            return True

    def _in_worker(self, job: ComputeJob) -> dict[str, Any]:
        """Computes `job` in a worker process (the caller counted it in `_pool_busy`)."""
        from concurrent.futures.process import BrokenProcessPool

        try:
            return self._processes().submit(compute_in_worker, job).result()
        except BrokenProcessPool as err:
            raise StageFailed(
                f"stage {job.item.stage.name} failed: its worker process died ({err})"
            ) from err
        finally:
            with self._pool_lock:
                self._pool_busy -= 1

    def _processes(self) -> ProcessPoolExecutor:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        with self._pool_lock:
            if self._pool is None:
                self._pool = ProcessPoolExecutor(
                    self.workers - 1,
                    multiprocessing.get_context("spawn"),
                    # Started from a stage's thread, which ends before the run does.
                    initializer=die_with_parent,
                    initargs=(os.getpid(), False),
                )
            return self._pool

    def __enter__(self) -> Slots:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        interrupted = exc_type is not None and issubclass(exc_type, (KeyboardInterrupt, SystemExit))
        if interrupted:
            # Ctrl-C or SIGTERM: stop the workers' stages now rather than wait for them (a
            # failed stage, not an interrupt, lets the others finish: nothing computed lost).
            if self._pool is not None:
                end_pool(self._pool)
            return
        for thread in self._threads:
            thread.join()
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)


def _picklable(job: ComputeJob) -> bool:
    try:
        pickle.dumps(job)
    except (pickle.PicklingError, AttributeError, TypeError):
        return False
    return True
