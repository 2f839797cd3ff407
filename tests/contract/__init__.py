"""The contract suite: hostile inputs against the README's contract, as a user would run them.

`make qa` runs it (`pytest tests/contract`); `make test` leaves it out (it takes tens of
minutes). `python -m tests.contract.run` runs the same cases and prints, per area, how many
were tried and held (`--only WORDS`, `--module NAME`, `--json`).

Adding a case: in a module `tests/contract/cases_<area>.py`, append to its `CASES: list[Case]`
a `Case(category, name, build, ...)` (`tests/contract/case.py`). `build(work)` writes the
hostile input into the empty work directory `work` and returns the `sonarmap` arguments; the
suite runs `python -m sonarmap.pipeline ARGS` there in a fresh interpreter and checks the exit
status (`expect_exit`, 2 by default), that stderr holds no traceback and, on exit 2, exactly one
short `error:` line, peak memory (`max_rss_mb`) and time (`max_seconds`), then the case's own
`check(work, done)`, if any (None when it held, else why not; `names(...)` in `case.py` makes
the common "the error names this" check). Inputs come from `sonarmap.*` and `tests.fixtures`
only (e.g. `small_recording`, `cached_run`), never from `tests.test_*` modules. A new module
is picked up by its name; `category/name` must be unique.
"""
