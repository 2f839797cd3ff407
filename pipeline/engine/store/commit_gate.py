"""Commits of one run's stage threads, closed at once when the run is interrupted.

On Ctrl-C (or SIGTERM) the main thread unwinds while a stage computed in this process
goes on in its thread. Two races followed: a stage that committed just before the
interrupt was not yet in the run record, so the next `gc` deleted finished work; and
the abandoned stage's temporary folder stayed in the store. The main thread closes the
gate: a commit in progress completes first and is reported, no later one starts, and
the folders of stages still computing are handed back for removal.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["NEVER_CLOSED", "CommitGate", "GateClosed"]


class GateClosed(Exception):
    """Raised in a stage thread that would start or commit after its run was interrupted."""


class CommitGate:
    """The open or closed gate of one run's commits (`ArtifactStore.staging` passes it)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._closed = False
        self._committed: list[tuple[str, str]] = []
        self._staging: set[Path] = set()

    @contextmanager
    def staging(self, tmp: Path) -> Iterator[None]:
        """Around creating a stage's temporary folder `tmp`, and its life after."""
        with self._lock:
            if self._closed:
                raise GateClosed(f"{tmp.name}: its run was interrupted")
            self._staging.add(tmp)
        try:
            yield
        finally:
            with self._lock:
                self._staging.discard(tmp)

    @contextmanager
    def committing(self, stage: str, key: str) -> Iterator[None]:
        """Around the commit (fsync, manifest, rename) of `stage`/`key`."""
        with self._lock:
            if self._closed:
                raise GateClosed(f"{stage}/{key[:12]}: its run was interrupted")
            yield
            self._committed.append((stage, key))

    def close(self) -> tuple[list[tuple[str, str]], list[Path]]:
        """Close the gate, after any commit in progress: (every (stage, key) committed
        through it, the temporary folders of stages still computing)."""
        with self._lock:
            self._closed = True
            return list(self._committed), sorted(self._staging)


class _NeverClosed(CommitGate):
    """The gate of a commit that belongs to no run (`pull`, `commit`): no lock, so the
    commits of parallel transfers do not wait for each other."""

    @contextmanager
    def staging(self, tmp: Path) -> Iterator[None]:
        yield

    @contextmanager
    def committing(self, stage: str, key: str) -> Iterator[None]:
        yield

    def close(self) -> tuple[list[tuple[str, str]], list[Path]]:  # pragma: no cover
        raise TypeError("the shared open gate is never closed")


NEVER_CLOSED = _NeverClosed()
"""Default gate of `ArtifactStore.staging`: always open."""
