"""Text for one-line messages: control characters escaped, long values and paths cut.

Every `error:` and `warning:` line quotes user data (paths, keys, values). A newline, a
carriage return or a terminal escape in it must not split the line or drive the terminal,
and a megabyte-long value or a 300-character path component must not flood it.
"""

from __future__ import annotations

import os
import re
import unicodedata

__all__ = [
    "MAX_LINE_CHARS",
    "MAX_PATH_CHARS",
    "display_path",
    "escape",
    "one_line",
    "scrub_userinfo",
    "shorten",
]

MAX_LINE_CHARS = 400
"""The longest message line printed (the one-line contract of docs/exit-codes.md)."""

MAX_PATH_CHARS = 160
"""Paths longer than this are shown with their middle elided (both ends name the file)."""

MAX_COMPONENT_CHARS = 80
"""Characters kept of one path component (a 64-hex artifact key stays whole)."""

_ELLIPSIS = "…"


def _escape_char(ch: str) -> str:
    """`\\n`-style escape of one character that must not reach the terminal raw."""
    named = {"\n": "\\n", "\r": "\\r", "\t": "\\t", "\x1b": "\\e"}
    if ch in named:
        return named[ch]
    code = ord(ch)
    if 0xDC80 <= code <= 0xDCFF:
        # A byte of a file name that is not UTF-8, as `os.fsdecode` carries it: shown as the
        # byte itself (`\xff`), as `ls -b` does, not as the surrogate's code point.
        return f"\\x{code - 0xDC00:02x}"
    if code <= 0xFF:
        return f"\\x{code:02x}"
    return f"\\u{code:04x}" if code <= 0xFFFF else f"\\U{code:08x}"


def _unsafe(ch: str) -> bool:
    # Cc: C0/C1 controls; Zl/Zp: line and paragraph separators; Cs: lone surrogates
    # (undecodable bytes of a path, which stderr could not encode).
    return unicodedata.category(ch) in ("Cc", "Zl", "Zp", "Cs")


def escape(text: str) -> str:
    """`text` with every control, separator or surrogate character escaped."""
    if not any(_unsafe(ch) for ch in text):
        return text
    return "".join(_escape_char(ch) if _unsafe(ch) else ch for ch in text)


def shorten(text: str, limit: int) -> str:
    """`text` cut in the middle to at most `limit` characters (its ends are kept)."""
    if len(text) <= limit:
        return text
    keep = limit - len(_ELLIPSIS)
    head = keep // 2
    return text[:head] + _ELLIPSIS + text[len(text) - (keep - head) :]


def _short_component(part: str) -> str:
    if len(part) <= MAX_COMPONENT_CHARS:
        return part
    tail = MAX_COMPONENT_CHARS // 4  # the end often names the file type
    return part[: MAX_COMPONENT_CHARS - tail] + _ELLIPSIS + part[-tail:]


def display_path(path: object) -> str:
    """A path as one safe, bounded piece of text (bytes paths decoded as the OS would):
    an over-long component (an ENAMETOOLONG name) is cut in its middle too."""
    text = os.fsdecode(path) if isinstance(path, bytes | os.PathLike) else str(path)
    text = "/".join(_short_component(p) for p in text.split("/"))
    return shorten(escape(text), MAX_PATH_CHARS)


def one_line(message: str, limit: int = MAX_LINE_CHARS) -> str:
    """`message` as a single printable line of at most `limit` characters."""
    return shorten(escape(message), limit)


_USERINFO = re.compile(r"(?i)\b([a-z][a-z0-9+.-]*://)[^/\s@'\"]*@")


def scrub_userinfo(text: str) -> str:
    """`text` with the user-info of every URL in it (`s3://KEY:SECRET@bucket`) replaced
    by `***`: libraries echo URLs, credentials included, in their errors."""
    return _USERINFO.sub(r"\1***@", text)
