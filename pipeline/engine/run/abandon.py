"""Runs an interrupt leaves behind on other threads, and what they still owe the store.

Ctrl-C unwinds the main thread only. A run on another thread (`follow`'s map updates)
keeps its lease and its temporary folders until its thread ends, and the process ends
first: the lease stayed in the store until `gc`. Each run registers how to close itself
while it is open; an interrupted command closes every one still open before it exits.
Imports nothing beyond the standard library: the command line imports it at start.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import threading
from collections.abc import Callable, Iterator

__all__ = ["abandon_open_runs", "while_open"]

log = logging.getLogger(__name__)

_lock = threading.Lock()
_open: dict[int, Callable[[], None]] = {}
_tokens = itertools.count()


@contextlib.contextmanager
def while_open(close: Callable[[], None]) -> Iterator[None]:
    """`close` is called by `abandon_open_runs` if the block has not left by then."""
    with _lock:
        token = next(_tokens)
        _open[token] = close
    try:
        yield
    finally:
        with _lock:
            _open.pop(token, None)


def abandon_open_runs() -> int:
    """Close every run still open, the innermost registered first; how many there were.
    A failing close is logged, and the others still run."""
    with _lock:
        closes = [_open.pop(token) for token in sorted(_open, reverse=True)]
    for close in closes:
        try:
            close()
        except Exception:  # an interrupted process leaves anyway; gc cleans what is left
            log.debug("closing an abandoned run failed", exc_info=True)
    return len(closes)
