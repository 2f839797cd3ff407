"""Benchmarks: each `bench_*.py` prints its figures as one JSON object (`make bench` runs them
all through `benchmarks/run_all.py`). Run one from the repo root as a module,

    .venv/bin/python -m benchmarks.bench_slam

They import `sonarmap.*` and the shared fixtures (`tests.fixtures`) only, never `tests.test_*`
modules and never through edits of `sys.path`.
"""
