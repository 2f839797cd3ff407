"""Atomic file output: written beside its destination, renamed into place on success.

The temporary file is created with mode 0666 filtered by the process umask, the mode
`open()` gives any new file, so every file sonarmap writes this way has the same
permissions (0644 under umask 022, 0664 under 002) whichever command wrote it. A failure
half-way leaves neither a partial destination nor the temporary file behind.
"""

from __future__ import annotations

import errno
import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO

__all__ = ["atomic_output"]


@contextmanager
def atomic_output(path: Path | str) -> Iterator[BinaryIO]:
    """Open a new file to stand in for `path`; on normal exit it is flushed, fsynced and
    renamed onto `path`, on an exception removed.

    Raises:
        OSError: the folder cannot be written, or the disk is full, over quota or read-only
            (naming `path`, not the temporary file: nothing partial is left behind).
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except OSError as err:
        raise _named(err, path, tmp) from err
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as err:
        tmp.unlink(missing_ok=True)
        if isinstance(err, OSError) and err.errno in _DISK_ERRNOS:
            raise _named(err, path, tmp) from err
        raise


_DISK_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG, errno.EIO})
"""A full, over-quota, read-only or failing disk: the output's fault, named by its path."""


def _named(err: OSError, path: Path, tmp: Path) -> OSError:
    """The error naming the destination where it names the temporary file or no file (a
    write to an open file names none), so the CLI prints `error: PATH: reason`, exit 2."""
    if err.filename is not None and str(err.filename) != str(tmp):
        return err
    return OSError(err.errno, err.strerror or os.strerror(err.errno or 0), str(path))
