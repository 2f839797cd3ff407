"""OSErrors from the store or a dataset as one-line `StoreError`s naming the path.

A full disk, a read-only store, a name too long for the filesystem: the user can fix
each, so they exit 2 like any bad input, with the path (its long components cut short)
and the system's own words for the errno.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
from pathlib import Path
from typing import Any

from sonarmap.pipeline.engine.errors import StoreError
from sonarmap.pipeline.engine.text import display_path

__all__ = [
    "delete_entry",
    "discard_artifact",
    "disk_error",
    "free_bytes",
    "fsync_dir",
    "fsync_file",
]


def disk_error(err: OSError, where: object = None) -> StoreError:
    """The one-line error for an OSError: the path (`where` when the error names none,
    e.g. a failed fsync or a library's write), the errno's text and name."""
    if err.errno is None:  # a library's OSError (pyarrow's write errors) has only text
        reason = str(err) or type(err).__name__
    else:
        reason = err.strerror or os.strerror(err.errno)
    reason = (reason.splitlines() or [""])[0][:120]
    if err.filename is not None:
        place = display_path(err.filename)
        if err.filename2 is not None:
            place += f" -> {display_path(err.filename2)}"
    else:
        place = "the artifact store" if where is None else f"writing {display_path(where)}"
    name = errno.errorcode.get(err.errno or -1)
    hint = {
        errno.ENOSPC: "; free space (`sonarmap gc` removes unreferenced artifacts) and run again",
        errno.EDQUOT: "; free space and run again",
        errno.EROFS: "; use a writable --store",
        errno.EACCES: "; check the permissions or use another --store",
        errno.ENAMETOOLONG: "; use shorter paths",
    }.get(err.errno or -1, "")
    return StoreError(f"{place}: {reason}{f' ({name})' if name else ''}{hint}")


def free_bytes(path: Path) -> int:
    """Free bytes on the disk holding `path` (or its nearest existing parent)."""
    probe = path
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    return shutil.disk_usage(probe).free


def delete_entry(path: Path) -> None:
    """Delete a directory tree, or a file or symbolic link (a link is unlinked: what it
    leads to is not the store's); gone already is fine."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def discard_artifact(store: Any, stage: str, key: str) -> None:
    """Move an artifact of `store` (an `ArtifactStore`) out of sight atomically, under its
    key's lock, then delete it (one forced to recompute, or a damaged copy replaced)."""
    with store.lock(stage, key):
        path = store.artifact_dir(stage, key)
        if path.exists() or path.is_symlink():
            trash = store.tmp_path(f"discard-{stage}")
            trash.parent.mkdir(parents=True, exist_ok=True)
            path.rename(trash)
            delete_entry(trash)


def fsync_dir(path: Path) -> None:
    """Flush a directory's entries (a rename into it) to disk; where the filesystem
    cannot, nothing."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def fsync_file(path: Path) -> None:
    """Flush a file's data to disk."""
    with path.open("rb") as f:
        os.fsync(f.fileno())
