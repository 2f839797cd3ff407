"""One hostile-input case of the contract suite (`tests/contract/`, run by `make qa`).

A case prepares files in an empty work directory and returns the `sonarmap` arguments
to run there; the campaign runs `python -m sonarmap.pipeline ARGS` in that directory as a new
user would (its own store under `data/store`, `COLUMNS=80`, output captured) and checks
the README's contract:

- the exit status is one of `expect_exit` (2 for bad input, 0 for a run that warns);
- no Python traceback on stderr, and on exit 2 exactly one `error:` line of at most
  `MAX_ERROR_CHARS` characters;
- peak memory (the child's `ru_maxrss`) under `max_rss_mb`, wall time under `max_seconds`;
- the case's own `check`, if any (e.g. "the artifacts of the live run still exist").

Cases live in `tests/contract/cases_*.py` modules, each exposing `CASES: list[Case]`.
"""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

MAX_ERROR_CHARS = 400
"""The longest one-line error the contract allows (a short prefix of a bad value)."""

Check = Callable[[Path, subprocess.CompletedProcess[str]], "str | None"]


@dataclass(frozen=True)
class Case:
    category: str
    """The QA report's category, e.g. "resources", "data loss", "exit codes", "empty maps"."""
    name: str
    build: Callable[[Path], list[str]]
    """Writes the hostile input into the work directory; returns the sonarmap arguments."""
    expect_exit: tuple[int, ...] = (2,)
    check: Check | None = None
    """Extra contract check after the run: None when it held, else why it did not."""
    max_rss_mb: float = 1024.0
    max_seconds: float = 10.0
    env: dict[str, str] = field(default_factory=dict)
    stdin: str | None = None


def error_line(done: subprocess.CompletedProcess[str]) -> str:
    """The first `error:` line on stderr ("" when there is none)."""
    return next((ln for ln in done.stderr.splitlines() if ln.startswith("error:")), "")


def names(*words: str) -> Check:
    """Check: the `error:` line names every word (the file, topic, key, field or reason)."""

    def check(_work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
        line = error_line(done)
        missing = [w for w in words if w not in line]
        return f"the error line does not name {missing}: {line[:200]!r}" if missing else None

    return check
