"""One-line error text for the CLI: control characters escaped, long paths shortened.

Every `error:` line the CLI prints goes through `one_line`, so a newline, a carriage
return or a terminal escape in a user's path (or in a message quoting one) cannot split
the line or drive the terminal; an `OSError` that names a file becomes `PATH: reason`.
"""

from __future__ import annotations

import errno
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from sonarmap.pipeline.engine.errors import OutputError, PipelineError
from sonarmap.pipeline.engine.text import MAX_LINE_CHARS, MAX_PATH_CHARS, display_path, one_line

__all__ = [
    "DISK_ERRNOS",
    "MAX_LINE_CHARS",
    "MAX_PATH_CHARS",
    "check_writable",
    "display_path",
    "one_line",
    "os_error_line",
    "writes_under",
]


def os_error_line(err: OSError) -> str | None:
    """`PATH: reason` for an OSError that names a file; None when it names none (a bug)."""
    if err.filename is None:
        return None
    reason = err.strerror or type(err).__name__
    line = f"{display_path(err.filename)}: {reason}"
    if err.filename2 is not None:
        line = f"{display_path(err.filename)} -> {display_path(err.filename2)}: {reason}"
    return line


DISK_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG})
"""A full, over-quota or read-only filesystem: the environment's fault, never a bug."""


def _disk_error(err: BaseException) -> OSError | None:
    """The disk-full / read-only OSError in `err`'s chain of causes, if any."""
    seen: set[int] = set()
    current: BaseException | None = err
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, OSError) and current.errno in DISK_ERRNOS:
            return current
        current = current.__cause__ or current.__context__
    return None


@contextmanager
def writes_under(*roots: Path | None) -> Iterator[None]:
    """Report a full or read-only disk met while writing under `roots` as `OutputError`.

    Writes to an open file fail with an OSError that names no file (and a stage's
    failure may wrap one); inside this block such a failure is blamed on the output
    folders the user named, so the CLI prints `error: ROOT: No space left on device`
    and exits 2. Any other error passes through unchanged.
    """
    try:
        yield
    except (OSError, PipelineError) as err:
        if isinstance(err, OSError) and err.filename is not None:
            raise  # already names its path
        if isinstance(err, PipelineError) and err.exit_code == 2:
            raise  # already bad input, with its own message
        disk = _disk_error(err)
        if disk is None:
            raise
        where = " or ".join(display_path(r) for r in roots if r is not None)
        reason = disk.strerror or os.strerror(disk.errno or 0)
        raise OutputError(f"{where}: {reason} (while writing results)") from err


def check_writable(folder: Path) -> None:
    """Create `folder` and prove it takes a file, before any work is paid for (an
    unwritable `--out` then fails in a second, not after the runs)."""
    folder.mkdir(parents=True, exist_ok=True)
    probe = folder / f".write-test-{os.getpid()}"
    probe.write_bytes(b"")
    probe.unlink()
