"""File transfers between a local store and an fsspec remote: streamed, capped, hashed.

Every byte read from a remote passes through `download`, which never writes past the
size the manifest declares and hashes while it copies, so a file that lies about its
size costs at most one chunk. `upload` skips a file the remote already holds with the
right size and sha256, which is what makes an interrupted push resumable. A small
thread pool runs the files of a batch concurrently; a byte progress bar goes to stderr
when it is a terminal.
"""

from __future__ import annotations

import hashlib
import os
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sonarmap.pipeline.engine.errors import ArtifactCorrupt, ConfigError, StoreError
from sonarmap.pipeline.engine.share.remotes import deadline, http_timeout

__all__ = [
    "CHUNK",
    "MAX_FILE_BYTES",
    "Job",
    "TransferStats",
    "download",
    "max_file_bytes",
    "run_jobs",
    "upload",
]

CHUNK = 1 << 20
MAX_FILE_BYTES = 64 << 30
"""Default cap on one file's declared size (`SONARMAP_MAX_FILE_BYTES` overrides it)."""
WORKERS = 4


def max_file_bytes() -> int:
    """The largest single file `pull` accepts, from `SONARMAP_MAX_FILE_BYTES` or the default.

    Raises:
        ConfigError: the variable is set but not a positive whole number of bytes (a limit
            a user tightened must not silently fall back to 64 GiB).
    """
    raw = os.environ.get("SONARMAP_MAX_FILE_BYTES", "").strip()
    if not raw:
        return MAX_FILE_BYTES
    if not raw.isdigit() or len(raw) > 19 or int(raw) <= 0:
        raise ConfigError(
            f"SONARMAP_MAX_FILE_BYTES={raw[:20]!r}: expected a whole number of bytes"
            " (1 to 9999999999999999999)"
        )
    return int(raw)


@dataclass
class TransferStats:
    """What a push or pull moved: files sent, files already at the destination, bytes."""

    sent: int = 0
    skipped: int = 0
    bytes: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def add(self, sent: bool, nbytes: int) -> None:
        with self._lock:
            if sent:
                self.sent += 1
                self.bytes += nbytes
            else:
                self.skipped += 1


Progress = Callable[[int], None]


class _Callback:
    """fsspec's transfer callback protocol, forwarding byte counts to a progress function."""

    def __init__(self, progress: Progress) -> None:
        self.progress = progress

    def set_size(self, size: int) -> None:
        pass

    def relative_update(self, inc: int = 1) -> None:
        self.progress(int(inc))

    def absolute_update(self, value: int) -> None:
        pass

    def branched(self, path_1: str, path_2: str, **kwargs: Any) -> None:
        return None

    def call(self, *args: Any, **kwargs: Any) -> None:
        pass


def _sha256_remote(fs: Any, path: str) -> str:
    digest = hashlib.sha256()
    with fs.open(path, "rb") as f:
        while chunk := f.read(CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def _remote_size(fs: Any, path: str) -> int | None:
    try:
        info = fs.info(path, **deadline(fs))
    except TimeoutError:
        raise  # the remote's (an OSError too): not "absent"
    except (FileNotFoundError, OSError):
        return None
    size = info.get("size")
    return int(size) if isinstance(size, int) else None


def upload(
    fs: Any, src: Path, dst: str, size: int, sha256: str, progress: Progress = lambda n: None
) -> bool:
    """Copy `src` to `dst` unless `dst` already has this size and sha256; True when sent."""
    if _remote_size(fs, dst) == size and _sha256_remote(fs, dst) == sha256:
        progress(size)
        return False
    parent = dst.rsplit("/", 1)[0]
    fs.makedirs(parent, exist_ok=True, **deadline(fs))
    if getattr(fs, "async_impl", False):
        # A link that goes quiet mid-upload leaves an async library (s3fs, sshfs) waiting
        # on a write that no read timeout covers: the whole file must be sent within a
        # deadline that grows with its size.
        fs.put_file(str(src), dst, callback=_Callback(progress), **deadline(fs, size))
        return True
    with src.open("rb") as fin, fs.open(dst, "wb") as fout:
        while chunk := fin.read(CHUNK):
            fout.write(chunk)
            progress(len(chunk))
    return True


def download(
    fs: Any,
    src: str,
    dst: Path,
    size: int,
    sha256: str,
    where: str,
    progress: Progress = lambda n: None,
) -> None:
    """Stream `src` into `dst`, refusing as soon as it runs past `size` bytes.

    Raises:
        ArtifactCorrupt: missing, larger or smaller than `size`, or another sha256
            (`where` names the artifact and file).
    """
    if size < 0:  # a read of size - written + 1 bytes would read it all at once
        raise ArtifactCorrupt(f"{where}: its manifest declares {size} bytes")
    digest = hashlib.sha256()
    written = 0
    try:
        kind = fs.info(src).get("type", "file")
    except FileNotFoundError as err:
        raise ArtifactCorrupt(f"{where} missing") from err
    if kind != "file":
        # A FIFO would block the open forever, a device never ends: neither is an artifact.
        raise ArtifactCorrupt(f"{where} is not a regular file ({str(kind)[:20]})")
    protocol = fs.protocol if isinstance(fs.protocol, str) else fs.protocol[0]
    # A plain web server may not serve byte ranges: read http(s) as one stream, within
    # a deadline that grows with the file's declared size (a trickle fails in bounded time).
    # (`size` given, fsspec asks no HEAD, and the timeout reaches aiohttp's GET: passed to
    # a HEAD, fsspec's sync wrapper would take `timeout` for its own.)
    kwargs: dict[str, Any] = {}
    if protocol in ("http", "https"):
        kwargs = (
            {"block_size": 0, "size": size, "timeout": http_timeout(size)}
            if size
            else {"block_size": 0}
        )
    try:
        fin = fs.open(src, "rb", **kwargs)
    except FileNotFoundError as err:
        raise ArtifactCorrupt(f"{where} missing") from err
    with fin, dst.open("wb") as fout:
        # One byte past the declared size is enough to know the file lies.
        while chunk := fin.read(min(CHUNK, size - written + 1)):
            if written + len(chunk) > size:
                raise ArtifactCorrupt(
                    f"{where} is larger than the {size} bytes its manifest declares"
                )
            fout.write(chunk)
            digest.update(chunk)
            written += len(chunk)
            progress(len(chunk))
    if written != size:
        raise ArtifactCorrupt(f"{where} has size {written}, its manifest says {size}")
    if digest.hexdigest() != sha256:
        raise ArtifactCorrupt(f"{where} sha256 does not match its manifest")


@dataclass(frozen=True)
class Job:
    """One file to move: `run(progress)` does it and says whether bytes were sent."""

    run: Callable[[Progress], bool]
    size: int


@contextmanager
def _progress_bar(total: int, label: str) -> Iterator[Progress]:
    if not sys.stderr.isatty() or total == 0:
        yield lambda n: None
        return
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        DownloadColumn,
        Progress,
        TextColumn,
        TransferSpeedColumn,
    )

    lock = threading.Lock()
    with Progress(
        TextColumn(label),
        BarColumn(),
        DownloadColumn(),
        TransferSpeedColumn(),
        console=Console(stderr=True),
        transient=True,
    ) as bar:
        task = bar.add_task(label, total=total)

        def advance(n: int) -> None:
            with lock:
                bar.advance(task, n)

        yield advance


def run_jobs(jobs: Sequence[Job], label: str, stats: TransferStats) -> None:
    """Run `jobs` on a small thread pool; the first failure is raised once all have stopped."""
    with _progress_bar(sum(j.size for j in jobs), label) as progress:
        if len(jobs) <= 1:
            for job in jobs:
                stats.add(job.run(progress), job.size)
            return
        with ThreadPoolExecutor(max_workers=WORKERS) as pool:
            futures = {pool.submit(job.run, progress): job for job in jobs}
            # Stop starting files at the first failure (a dead remote would otherwise make
            # every queued file wait out its own timeout); the running ones end on theirs.
            _, pending = wait(futures, return_when=FIRST_EXCEPTION)
            for fut in pending:
                fut.cancel()
            first: BaseException | None = None
            for fut, job in futures.items():
                if fut.cancelled():
                    continue
                try:
                    stats.add(fut.result(), job.size)
                except BaseException as err:  # re-raised below, after the pool drains
                    first = first or err
            if first is not None:
                raise first


def os_error(err: OSError, path: str) -> StoreError:
    """One line for a failed write or read at `path` (disk full, read-only, permissions)."""
    reason = err.strerror or type(err).__name__
    return StoreError(f"{path}: {reason}")
