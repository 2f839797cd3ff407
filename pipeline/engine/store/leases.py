"""Leases: the artifacts a running process uses, so `gc` leaves them alone.

A run holds `<store>/.leases/<id>.lock` under an exclusive `flock` for its whole life
and lists the `stage/key` addresses it reads or commits in `<id>.json` (replaced
atomically as it grows). The kernel drops the flock when the process ends, however it
ends (kill -9 included), so a lease whose lock can be taken is stale: `gc` removes it
and no longer protects its addresses. The lock file is created under a temporary name
and renamed into place only once locked, so a lease never looks stale while its owner
is starting. Where the filesystem refuses flock, the pid decides (same host only).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import socket
import time
import uuid
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

__all__ = ["LEASES", "LeaseScan", "RunLease", "pid_alive", "scan_leases"]

LEASES = ".leases"


class RunLease:
    """A running process's claim on store addresses (a context manager)."""

    def __init__(self, root: Path) -> None:
        self.dir = Path(root) / LEASES
        # The pid leads the name so `gc` can clean a killed owner's temporaries.
        self.id = f"{os.getpid()}-{uuid.uuid4().hex[:12]}"
        self.addresses: set[str] = set()
        self.started_at = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        self._fd: int | None = None

    @property
    def lock_path(self) -> Path:
        return self.dir / f"{self.id}.lock"

    @property
    def json_path(self) -> Path:
        return self.dir / f"{self.id}.json"

    def __enter__(self) -> RunLease:
        self.dir.mkdir(parents=True, exist_ok=True)
        tmp = self.dir / f".{self.id}.lock.tmp"
        fd = os.open(tmp, os.O_CREAT | os.O_RDWR, 0o644)
        try:
            with contextlib.suppress(OSError):  # no flock here: the pid decides
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            os.rename(tmp, self.lock_path)
        except BaseException:
            os.close(fd)
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise
        self._fd = fd
        self._write()
        return self

    def add(self, addresses: Iterable[str]) -> None:
        """Claim more addresses; written before the caller reads or commits them."""
        new = set(addresses) - self.addresses
        if new:
            self.addresses |= new
            self._write()

    def _write(self) -> None:
        doc = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started_at": self.started_at,
            "addresses": sorted(self.addresses),
        }
        tmp = self.dir / f".{self.id}.json.tmp"
        tmp.write_text(json.dumps(doc, sort_keys=True))
        os.replace(tmp, self.json_path)

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.release()

    def release(self) -> None:
        """Give up the claim (again: nothing); also from another thread than its run's."""
        # The json goes first: a lock without its json is an orphan `gc` cleans.
        for path in (self.json_path, self.lock_path):
            with contextlib.suppress(OSError):
                path.unlink()
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


@dataclass
class LeaseScan:
    """What the leases of a store say: the addresses live runs hold."""

    addresses: set[tuple[str, str]] = field(default_factory=set)
    live: int = 0
    stale_removed: int = 0


def pid_alive(pid: int) -> bool:
    """Whether a process with this pid exists on this host (ours counts as alive)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _owner_gone(lock: Path, doc: dict[str, object] | None) -> tuple[bool, int | None]:
    """(stale?, an fd holding the lock when it was taken: the caller closes it)."""
    try:
        fd = os.open(lock, os.O_RDWR)
    except FileNotFoundError:
        return True, None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return False, None
    except OSError as err:  # flock unsupported (some network filesystems)
        os.close(fd)
        if err.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.EINVAL):
            raise
        if doc is None or doc.get("host") != socket.gethostname():
            return False, None
        pid = doc.get("pid")
        return not (isinstance(pid, int) and pid_alive(pid)), None
    return True, fd


def _read(path: Path) -> dict[str, object] | None:
    with contextlib.suppress(OSError, ValueError):
        doc = json.loads(path.read_text())
        if isinstance(doc, dict):
            return doc
    return None


def _addresses(doc: dict[str, object]) -> Iterator[tuple[str, str]]:
    items = doc.get("addresses")
    for item in items if isinstance(items, list) else []:
        if isinstance(item, str) and "/" in item:
            stage, _, key = item.partition("/")
            yield stage, key


def scan_leases(root: Path, *, prune: bool) -> LeaseScan:
    """The addresses held by live runs; with `prune`, dead runs' leases are removed."""
    result = LeaseScan()
    folder = Path(root) / LEASES
    if not folder.is_dir():
        return result
    jsons = {p.stem: p for p in folder.glob("*.json")}
    locks = {p.stem: p for p in folder.glob("*.lock")}
    for stem in sorted(set(jsons) | set(locks)):
        doc = _read(jsons[stem]) if stem in jsons else None
        stale, fd = _owner_gone(folder / f"{stem}.lock", doc)
        if not stale:
            result.live += 1
            if doc is not None:
                result.addresses.update(_addresses(doc))
            continue
        try:
            if prune:
                for path in (folder / f"{stem}.json", folder / f"{stem}.lock"):
                    with contextlib.suppress(FileNotFoundError):
                        path.unlink()
                result.stale_removed += 1
        finally:
            if fd is not None:
                os.close(fd)
    return result
