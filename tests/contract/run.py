"""The contract suite's own runner: every case, then how many were tried and held per area.

    python -m tests.contract.run [--only SUBSTRING] [--module NAME] [--json]   (repo root)

Runs every case of `tests/contract/cases_*.py` (see `tests/contract/__init__.py`) as its own
`python -m sonarmap.pipeline` process in a fresh directory, and prints, per category, how many
cases were tried and how many held, then the cases that did not hold and why. Exit 0 when
every case held, 1 otherwise. `make qa` runs the same cases through pytest
(`tests/contract/test_contract.py`), which prints the same table at its end.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from tests.contract.case import MAX_ERROR_CHARS, Case

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]


def load_cases(module: str = "*") -> list[Case]:
    cases: list[Case] = []
    for module_path in sorted(HERE.glob(f"cases_{module}.py")):
        cases.extend(importlib.import_module(f"tests.contract.{module_path.stem}").CASES)
    return cases


def case_id(case: Case) -> str:
    return f"{case.category}/{case.name}"


def _run(case: Case, workdir: Path) -> tuple[subprocess.CompletedProcess[str], float, float]:
    args = case.build(workdir)
    env = {**os.environ, "COLUMNS": "80", "PYTHONPATH": str(ROOT), **case.env}
    start = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-m", "sonarmap.pipeline", *args],
        cwd=workdir,
        env=env,
        stdin=subprocess.PIPE if case.stdin is not None else subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        out, err = proc.communicate(case.stdin, timeout=max(case.max_seconds * 3, 30))
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, 9)
        out, err = proc.communicate()
    seconds = time.monotonic() - start
    # ru_maxrss of the children waited for so far: the largest is the one just run,
    # unless an earlier case used more; so each case runs in a fresh interpreter (verdict).
    rss_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    return subprocess.CompletedProcess(args, proc.returncode, out, err), seconds, rss_mb


def judge(case: Case, workdir: Path) -> tuple[str | None, dict[str, float]]:
    """None when the case held, else the first broken clause of the contract."""
    done, seconds, rss_mb = _run(case, workdir)
    figures = {"seconds": round(seconds, 2), "rss_mb": round(rss_mb, 1)}
    if done.returncode not in case.expect_exit:
        tail = done.stderr.strip().splitlines()[-1:] or [""]
        return f"exit {done.returncode}, expected {case.expect_exit}: {tail[0][:160]}", figures
    if "Traceback (most recent call last)" in done.stderr:
        return "traceback on stderr", figures
    if done.returncode == 2:
        errors = [ln for ln in done.stderr.splitlines() if ln.startswith("error:")]
        if len(errors) != 1:
            return f"{len(errors)} error lines", figures
        if len(errors[0]) > MAX_ERROR_CHARS:
            return f"error line of {len(errors[0])} characters", figures
    if rss_mb > case.max_rss_mb:
        return f"peak RSS {rss_mb:.0f} MB > {case.max_rss_mb:.0f} MB", figures
    if seconds > case.max_seconds:
        return f"{seconds:.1f} s > {case.max_seconds:.0f} s", figures
    if case.check is not None:
        return case.check(workdir, done), figures
    return None, figures


def _one(name: str) -> None:
    """Child mode: judge one case in this fresh interpreter, print its verdict as JSON."""
    case = next(c for c in load_cases() if case_id(c) == name)
    with tempfile.TemporaryDirectory(prefix="sonarmap-qa-") as tmp:
        why, figures = judge(case, Path(tmp))
    print(json.dumps({"why": why, **figures}))


def verdict(case: Case) -> dict[str, object]:
    """{"why": None or the broken clause, "seconds", "rss_mb"}: the case judged in a fresh
    interpreter (its children's peak memory is its own)."""
    child = subprocess.run(
        [sys.executable, "-m", "tests.contract.run", "--one", case_id(case)],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    try:
        return dict(json.loads(child.stdout.strip().splitlines()[-1]))
    except (IndexError, json.JSONDecodeError):
        return {"why": f"contract child failed: {child.stderr.strip()[-200:]}"}


def table(verdicts: dict[str, dict[str, object]]) -> list[str]:
    """The per-category summary ("tried N  held M"), then the cases that did not hold."""
    tried: Counter[str] = Counter()
    held: Counter[str] = Counter()
    for name, v in verdicts.items():
        category = name.split("/", 1)[0]
        tried[category] += 1
        held[category] += v["why"] is None
    rows = [f"{c:<24} tried {tried[c]:>3}  held {held[c]:>3}" for c in sorted(tried)]
    rows.append(f"{'all':<24} tried {sum(tried.values()):>3}  held {sum(held.values()):>3}")
    rows += [f"  not held: {n}: {v['why']}" for n, v in verdicts.items() if v["why"] is not None]
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default="", help="run the cases whose category/name holds this")
    parser.add_argument("--module", default="*", help="only tests/contract/cases_MODULE.py")
    parser.add_argument("--json", action="store_true", help="one JSON document on stdout")
    parser.add_argument("--one", default=None, help=argparse.SUPPRESS)
    opts = parser.parse_args()
    if opts.one is not None:
        _one(opts.one)
        return 0
    verdicts: dict[str, dict[str, object]] = {}
    for case in load_cases(opts.module):
        name = case_id(case)
        if opts.only not in name:
            continue
        verdicts[name] = verdict(case)
        print(f"{'held' if verdicts[name]['why'] is None else 'FAIL'}  {name}", file=sys.stderr)
    failures = [{"case": n, **v} for n, v in verdicts.items() if v["why"] is not None]
    if opts.json:
        tried = Counter(n.split("/", 1)[0] for n in verdicts)
        held = Counter(n.split("/", 1)[0] for n, v in verdicts.items() if v["why"] is None)
        categories = {c: {"tried": tried[c], "held": held[c]} for c in sorted(tried)}
        print(json.dumps({"categories": categories, "failures": failures}, indent=1))
    else:
        print("\n".join(table(verdicts)))
    return 0 if not failures else 1


if __name__ == "__main__":
    sys.exit(main())
