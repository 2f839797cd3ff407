"""Atomic file output: written beside its destination, renamed into place on success.

The temporary file is created with mode 0666 filtered by the process umask, the mode
`open()` gives any new file, so every file sonarmap writes this way has the same
permissions (0644 under umask 022, 0664 under 002) whichever command wrote it. A failure
half-way leaves neither a partial destination nor the temporary file behind.
"""

from __future__ import annotations

import errno
import os
import stat
import uuid
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO

__all__ = ["atomic_output", "check_output_path"]


def _kind(mode: int) -> str:
    """What a non-regular directory entry is, in words."""
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return "not a regular file"


def check_output_path(path: Path | str, inputs: Iterable[Path | str] = ()) -> None:
    """Refuse to write `path` where the write would destroy something that is not an
    earlier output: an existing entry that is not a regular file (a device such as
    /dev/null, a FIFO, a directory, a symbolic link: the rename would replace the entry
    itself, not write through it) or one of `inputs` (converting a recording onto itself
    would replace it). A missing path, or an existing regular file, passes.

    Raises:
        OSError: naming `path` (the CLI prints `error: PATH: reason`, exit 2).
    """
    path = Path(path)
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    except OSError as err:
        raise OSError(err.errno, err.strerror or "cannot be inspected", str(path)) from err
    if not stat.S_ISREG(mode):
        raise OSError(
            errno.EEXIST,
            f"exists and is {_kind(mode)}; refusing to replace it (give a new file's path)",
            str(path),
        )
    for given in inputs:
        try:
            same = os.path.samefile(path, given)
        except OSError:
            continue
        if same:
            raise OSError(
                errno.EEXIST,
                f"is the input {given}; refusing to overwrite it (give another output path)",
                str(path),
            )


@contextmanager
def atomic_output(path: Path | str) -> Iterator[BinaryIO]:
    """Open a new file to stand in for `path`; on normal exit it is flushed, fsynced and
    renamed onto `path`, on an exception removed.

    Raises:
        OSError: `path` is not a regular file where it exists (`check_output_path`: it is
            checked again when the file is renamed into place), the folder cannot be written,
            or the disk is full, over quota or read-only (naming `path`, not the temporary
            file: nothing partial is left behind).
    """
    path = Path(path)
    check_output_path(path)
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
        check_output_path(path)  # it may have appeared while the output was written
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
