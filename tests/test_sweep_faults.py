"""Sweeps refuse bad inputs before the first run, report failed runs with a non-zero exit
after writing the tables, and their pool workers die with the sweep's process."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from sonarmap.pipeline.experiments.sweep import RunOutcome
from sonarmap.pipeline.experiments.sweep_checks import failure_exit_code
from tests.fixtures.signals import default_sigint

TESTS = Path(__file__).resolve().parent


def _sweep(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "sonarmap.pipeline", "sweep", *args],
        capture_output=True,
        text=True,
        timeout=120,
        env=os.environ.copy(),
    )


def _calls(tmp_path: Path) -> list[str]:
    log = tmp_path / "calls.log"
    return log.read_text().splitlines() if log.exists() else []


def test_missing_dataset_is_refused_before_any_run(toy_env: list[Path], tmp_path: Path) -> None:
    missing = tmp_path / "missing.bin"
    res = _sweep(
        *map(str, toy_env),
        str(missing),
        "--store",
        str(tmp_path / "s"),
        "--out",
        str(tmp_path / "o"),
    )
    assert res.returncode == 2, res.stderr
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert errors == [f"error: {missing}: no such file or directory"]
    assert "Traceback" not in res.stderr
    assert _calls(tmp_path) == []  # not one stage ran


def test_bad_config_point_is_refused_before_any_run(toy_env: list[Path], tmp_path: Path) -> None:
    res = _sweep(
        *map(str, toy_env),
        "--set",
        "double.factor=2,two",
        "--store",
        str(tmp_path / "s"),
        "--out",
        str(tmp_path / "o"),
    )
    assert res.returncode == 2, res.stderr
    assert "double.factor" in res.stderr and "Traceback" not in res.stderr
    assert _calls(tmp_path) == []


def test_unwritable_out_is_refused_before_any_run(toy_env: list[Path], tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    res = _sweep(*map(str, toy_env), "--store", str(tmp_path / "s"), "--out", str(blocker / "o"))
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().splitlines()[-1].startswith(f"error: {blocker}")
    assert _calls(tmp_path) == []


def test_failed_runs_exit_nonzero_after_the_others_and_the_tables(
    toy_env: list[Path], tmp_path: Path
) -> None:
    out = tmp_path / "o"
    res = _sweep(
        *map(str, toy_env),
        "--set",
        "summary.fail=false,true",
        "--store",
        str(tmp_path / "s"),
        "--out",
        str(out),
        "-j",
        "2",
    )
    assert res.returncode == 1, res.stderr  # the toy stage's RuntimeError is a bug, not input
    failed = [ln for ln in res.stderr.splitlines() if ln.startswith("failed:")]
    assert sorted(failed) == sorted(
        f"failed: {d} [summary.fail=true]: stage summary failed: RuntimeError: deliberate failure"
        for d in toy_env
    )
    assert len([ln for ln in res.stderr.splitlines() if ln.startswith("error:")]) == 1
    table = (out / "table.md").read_text()
    assert "| summary.fail=false | 2 |" in table  # the good runs were finished and tabled
    assert (out / "sweep.parquet").stat().st_size > 0


def test_exit_code_is_2_only_when_every_failure_is_bad_input() -> None:
    ok = RunOutcome("a", {}, "ok", 1.0)
    bad_input = RunOutcome("b", {}, "failed", 1.0, error="b: not a recording", exit_code=2)
    bug = RunOutcome("c", {}, "failed", 1.0, error="KeyError", exit_code=1)
    assert failure_exit_code([ok, ok]) == 0
    assert failure_exit_code([ok, bad_input]) == 2
    assert failure_exit_code([bad_input, bug, ok]) == 1


def _alive(pid: int) -> bool:
    """True while `pid` runs (a zombie waiting for its reaper counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")


def _two_workers_in_double(proc: subprocess.Popen[Any], tmp_path: Path) -> set[int]:
    """The pids of the two pool workers once both are inside the toy's sleeping stage."""
    workers: set[int] = set()
    deadline = time.monotonic() + 60
    while len(workers) < 2 and time.monotonic() < deadline and proc.poll() is None:
        workers = {int(ln.split()[1]) for ln in _calls(tmp_path) if ln.startswith("double")}
        time.sleep(0.1)
    assert len(workers) == 2, "both workers should be inside the sleeping stage"
    return workers


def _kill_what_is_left(proc: subprocess.Popen[Any], tmp_path: Path) -> None:
    if proc.poll() is None:
        proc.kill()
    for line in _calls(tmp_path):
        pid = int(line.split()[1])
        if _alive(pid) and pid != os.getpid():
            os.kill(pid, signal.SIGKILL)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_workers_die_with_the_sweep_process(toy_env: list[Path], tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "sonarmap.pipeline",
            "sweep",
            *map(str, toy_env),
            "--set",
            "double.sleep_s=60",
            "--store",
            str(tmp_path / "s"),
            "--out",
            str(tmp_path / "o"),
            "-j",
            "2",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=os.environ.copy(),
    )
    try:
        workers = _two_workers_in_double(proc, tmp_path)
        assert proc.pid not in workers
        os.kill(proc.pid, signal.SIGKILL)  # the parent alone, not its process group
        proc.wait()
        deadline = time.monotonic() + 15
        while any(_alive(p) for p in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not [p for p in workers if _alive(p)], "workers outlived the sweep"
    finally:
        _kill_what_is_left(proc, tmp_path)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize(
    ("sig", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGHUP, 129)]
)
def test_an_interrupted_parallel_sweep_stops_now_and_starts_no_queued_run(
    toy_env: list[Path], tmp_path: Path, sig: signal.Signals, status: int
) -> None:
    """Campaign 14 #1, #3, #7: with -j 2 the pool's shutdown waited for every queued run
    (one still started after Ctrl-C); SIGTERM ended without the line; SIGHUP unwound nothing."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "sonarmap.pipeline", "sweep", str(toy_env[0]),
         "--set", "double.factor=2,3,4", "--set", "double.sleep_s=60",
         "--store", str(tmp_path / "s"), "--out", str(tmp_path / "o"), "-j", "2"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=os.environ.copy(),
        preexec_fn=default_sigint,
    )  # fmt: skip
    try:
        workers = _two_workers_in_double(proc, tmp_path)
        t0 = time.monotonic()
        os.kill(proc.pid, sig)  # the parent alone
        _, stderr = proc.communicate(timeout=30)
        assert time.monotonic() - t0 < 15  # not the 60 s the running points would take
        assert proc.returncode == status, stderr
        assert "sweep: interrupted after 0 of 3 runs" in stderr
        assert sum(ln.startswith("double") for ln in _calls(tmp_path)) == 2  # none queued ran
        assert not [p for p in workers if _alive(p)], "workers outlived the sweep"
        assert not list((tmp_path / "s" / ".leases").glob("*.json"))
    finally:
        _kill_what_is_left(proc, tmp_path)
