"""Atomic file output: written beside its destination, renamed into place on success.

The temporary file is created with mode 0666 filtered by the process umask, the mode
`open()` gives any new file, so every file sonarmap writes this way has the same
permissions (0644 under umask 022, 0664 under 002) whichever command wrote it. A failure
half-way leaves neither a partial destination nor the temporary file behind.
"""

from __future__ import annotations

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
        OSError: the folder cannot be written (callers name the path in their error).
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
