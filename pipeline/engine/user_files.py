"""The one way sonarmap reads a small file a user gives it (config, COCO, geometry.json,
annotation file, beam table, message definition, an existing output to compare with).

- The file is opened first (non-blocking, so a FIFO cannot hang the open) and `fstat` on
  the open handle says it is a regular file: a FIFO, a device (`/dev/zero` behind a
  symlink reports 0 bytes) or a folder is refused, and nothing can be swapped in between
  a check and the read.
- At most `max_bytes + 1` bytes are read, so a file that grows meanwhile, or lies about
  its size, is refused at the cap, never read to its end.
- Parsers are bounded by the callers (`yaml_files`' node and depth caps; JSON's depth
  through RecursionError and its size through the byte cap).

Every refusal is one `error` line naming the file.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import Any, BinaryIO

from sonarmap.pipeline.engine.errors import PipelineError
from sonarmap.pipeline.engine.text import one_line

__all__ = ["open_user_file", "read_user_file", "read_user_json"]


def open_user_file(path: Path | str, what: str, error: type[PipelineError]) -> BinaryIO:
    """A regular file opened for binary reading (checked on the open handle), for a
    caller that reads it in bounded pieces (a recording of any size).

    Raises:
        error: missing, unreadable or not a regular file (one line naming the file).
    """
    where = one_line(str(path))
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0)
    try:
        fd = os.open(path, flags)
    except OSError as err:
        raise error(f"{where}: cannot read {what} ({err.strerror or err})") from err
    try:
        info = os.fstat(fd)
    except OSError as err:
        os.close(fd)
        raise error(f"{where}: cannot read {what} ({err.strerror or err})") from err
    if not stat.S_ISREG(info.st_mode):
        os.close(fd)
        raise error(f"{where}: {what} is not a regular file ({_kind(info.st_mode)})")
    return os.fdopen(fd, "rb")


def read_user_file(
    path: Path | str, what: str, error: type[PipelineError], max_bytes: int
) -> bytes:
    """The bytes of a regular file of at most `max_bytes`.

    Raises:
        error: missing, unreadable, not a regular file, or over `max_bytes` (one line
            naming the file and the cap).
    """
    where = one_line(str(path))
    f = open_user_file(path, what, error)
    try:
        with f:
            size = os.fstat(f.fileno()).st_size
            if size > max_bytes:
                raise error(f"{where}: {what} is {size} bytes, over the limit of {max_bytes}")
            data = f.read(max_bytes + 1)
    except OSError as err:
        raise error(f"{where}: cannot read {what} ({err.strerror or err})") from err
    if len(data) > max_bytes:
        raise error(f"{where}: {what} is over the limit of {max_bytes} bytes")
    return data


def _kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return name
    return "not a plain file"


def read_user_json(path: Path | str, what: str, error: type[PipelineError], max_bytes: int) -> Any:
    """A JSON document read by `read_user_file`: NaN/Infinity refused, depth bounded.

    Raises:
        error: as `read_user_file`, or not JSON (one line naming the file).
    """
    data = read_user_file(path, what, error, max_bytes)
    try:
        return json.loads(data, parse_constant=_no_constant)
    except (ValueError, RecursionError) as err:
        # UnicodeDecodeError is a ValueError: bytes that are not UTF-8 land here too.
        msg = (
            one_line(str(err), 120) if not isinstance(err, RecursionError) else "nested too deeply"
        )
        raise error(f"{one_line(str(path))}: not a {what} ({msg})") from None


def _no_constant(name: str) -> None:
    raise ValueError(f"{name} is not a JSON number")
