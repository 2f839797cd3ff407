"""OSErrors from the store or a dataset as one-line `StoreError`s naming the path.

A full disk, a read-only store, a name too long for the filesystem: the user can fix
each, so they exit 2 like any bad input, with the path (its long components cut short)
and the system's own words for the errno.
"""

from __future__ import annotations

import errno
import os

from pipeline.engine.errors import StoreError

__all__ = ["disk_error", "short_path"]

_COMPONENT = 80  # characters kept of one path component (a 64-hex key stays whole)
_TOTAL = 240  # characters kept of the whole path


def short_path(path: object) -> str:
    """`path` on one line: control characters escaped, long components and long paths
    cut short (an ENAMETOOLONG name is quoted, not printed whole)."""
    text = os.fsdecode(path) if isinstance(path, str | bytes | os.PathLike) else str(path)
    parts = [
        p if len(p) <= _COMPONENT else f"{p[:_COMPONENT]}...({len(p)} chars)"
        for p in text.split("/")
    ]
    text = "/".join(parts)
    if len(text) > _TOTAL:
        text = f"...{text[-_TOTAL:]}"
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def disk_error(err: OSError, where: object = None) -> StoreError:
    """The one-line error for an OSError: the path (`where` when the error names none,
    e.g. a failed fsync or a library's write), the errno's text and name."""
    if err.errno is None:  # a library's OSError (pyarrow's write errors) has only text
        reason = str(err) or type(err).__name__
    else:
        reason = err.strerror or os.strerror(err.errno)
    reason = (reason.splitlines() or [""])[0][:120]
    if err.filename is not None:
        place = short_path(err.filename)
        if err.filename2 is not None:
            place += f" -> {short_path(err.filename2)}"
    else:
        place = "the artifact store" if where is None else f"writing {short_path(where)}"
    name = errno.errorcode.get(err.errno or -1)
    hint = {
        errno.ENOSPC: "; free space (`sonarmap gc` removes unreferenced artifacts) and run again",
        errno.EDQUOT: "; free space and run again",
        errno.EROFS: "; use a writable --store",
        errno.EACCES: "; check the permissions or use another --store",
        errno.ENAMETOOLONG: "; use shorter paths",
    }.get(err.errno or -1, "")
    return StoreError(f"{place}: {reason}{f' ({name})' if name else ''}{hint}")
