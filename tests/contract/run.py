"""The QA campaign: hostile inputs against the README's contract, counted per category.

    python benchmarks/qa_campaign.py [--only SUBSTRING] [--module NAME] [--json]

Runs every case of `benchmarks/qa/cases_*.py` (see `benchmarks/qa/case.py`) as its own
`python -m sonarmap.pipeline` process in a fresh directory, and prints, per category, how many
cases were tried and how many held, then the cases that did not hold and why. Exit 0
when every case held, 1 otherwise. It is a study, not a test: the suite keeps one test
per fault class; this campaign tries more variants and measures memory and time.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

from benchmarks.qa.case import MAX_ERROR_CHARS, Case  # noqa: E402


def load_cases(module: str = "*") -> list[Case]:
    cases: list[Case] = []
    for module_path in sorted((HERE / "qa").glob(f"cases_{module}.py")):
        module = importlib.import_module(f"benchmarks.qa.{module_path.stem}")
        cases.extend(module.CASES)
    return cases


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
    # unless an earlier case used more; so each case runs in a fresh interpreter below.
    import resource

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
    case = next(c for c in load_cases() if f"{c.category}/{c.name}" == name)
    with tempfile.TemporaryDirectory(prefix="sonarmap-qa-") as tmp:
        why, figures = judge(case, Path(tmp))
    print(json.dumps({"why": why, **figures}))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default="", help="run the cases whose category/name holds this")
    parser.add_argument("--module", default="*", help="only benchmarks/qa/cases_MODULE.py")
    parser.add_argument("--json", action="store_true", help="one JSON document on stdout")
    parser.add_argument("--one", default=None, help=argparse.SUPPRESS)
    opts = parser.parse_args()
    if opts.one is not None:
        _one(opts.one)
        return 0
    tried: Counter[str] = Counter()
    held: Counter[str] = Counter()
    failures: list[dict[str, object]] = []
    for case in load_cases(opts.module):
        name = f"{case.category}/{case.name}"
        if opts.only not in name:
            continue
        child = subprocess.run(
            [sys.executable, __file__, "--one", name], capture_output=True, text=True
        )
        try:
            verdict = json.loads(child.stdout.strip().splitlines()[-1])
        except (IndexError, json.JSONDecodeError):
            verdict = {"why": f"campaign child failed: {child.stderr.strip()[-200:]}"}
        tried[case.category] += 1
        if verdict["why"] is None:
            held[case.category] += 1
        else:
            failures.append({"case": name, **verdict})
        print(f"{'held' if verdict['why'] is None else 'FAIL'}  {name}", file=sys.stderr)
    table = {c: {"tried": tried[c], "held": held[c]} for c in sorted(tried)}
    if opts.json:
        print(json.dumps({"categories": table, "failures": failures}, indent=1))
    else:
        for category, row in table.items():
            print(f"{category:<24} tried {row['tried']:>3}  held {row['held']:>3}")
        total = sum(tried.values())
        print(f"{'all':<24} tried {total:>3}  held {sum(held.values()):>3}")
        for failure in failures:
            print(f"  not held: {failure['case']}: {failure['why']}")
    return 0 if not failures else 1


if __name__ == "__main__":
    sys.exit(main())
