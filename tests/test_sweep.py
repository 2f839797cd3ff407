"""Sweeps: cross product, shared artifacts computed once, failures isolated, local and Ray."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from toy_stages import GRAPH

from sonarmap.pipeline.experiments.sweep import expand, run_sweep
from sonarmap.pipeline.experiments.sweep_output import write_sweep

TESTS = Path(__file__).resolve().parent


def _calls(tmp_path: Path) -> list[str]:
    return [ln.split()[0] for ln in (tmp_path / "calls.log").read_text().splitlines() if ln]


def test_expand_is_the_cross_product(tmp_path: Path) -> None:
    specs = expand([tmp_path / "a", tmp_path / "b"], ["x.k=1,2", "y.j=a,b,c"])
    assert len(specs) == 12
    assert specs[0].override_args == ["x.k=1", "y.j=a"]


def test_local_sweep_shares_artifacts_and_isolates_failures(
    toy_env: list[Path], tmp_path: Path
) -> None:
    specs = expand(
        toy_env, ["double.factor=2,3", "summary.fail=false,true"], store=tmp_path / "store"
    )
    outcomes = run_sweep(specs, executor="local", jobs=2, graph=GRAPH)
    assert [o.status for o in outcomes].count("failed") == 4
    assert all("summary" in (o.error or "") for o in outcomes if o.status == "failed")
    calls = _calls(tmp_path)
    assert calls.count("source") == 2  # once per dataset, shared by its 4 runs
    assert calls.count("double") == 4  # once per (dataset, factor)
    doc = write_sweep(outcomes, tmp_path / "out")
    assert len(doc["runs"]) == 8 and len(doc["groups"]) == 4
    assert (tmp_path / "out" / "sweep.parquet").stat().st_size > 0
    assert "double.factor=2" in (tmp_path / "out" / "table.md").read_text()


def test_cli_sweep_json(toy_env: list[Path], tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from sonarmap.pipeline.cli import app

    res = CliRunner().invoke(
        app,
        [
            "sweep",
            *map(str, toy_env),
            "--set",
            "count.bins=3,5",
            "--store",
            str(tmp_path / "s"),
            "--out",
            str(tmp_path / "o"),
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert {r["status"] for r in doc["runs"]} == {"ok"}
    assert all(r["summary"] is not None for r in doc["runs"])


def test_ray_sweep_runs_on_a_real_local_ray_instance(toy_env: list[Path], tmp_path: Path) -> None:
    pytest.importorskip("ray")
    specs = expand(toy_env, ["double.factor=2,3"], store=tmp_path / "store")
    outcomes = run_sweep(specs, executor="ray", jobs=2, graph=GRAPH)
    assert [o.status for o in outcomes] == ["ok"] * 4
    calls = _calls(tmp_path)
    assert calls.count("source") == 2 and calls.count("double") == 4
    pids = {ln.split()[1] for ln in (tmp_path / "calls.log").read_text().splitlines()}
    assert str(os.getpid()) not in pids  # computed in Ray worker processes


def test_cli_sweep_never_starts_more_processes_than_runs(
    toy_env: list[Path], tmp_path: Path
) -> None:
    """`-j 4096` forked 4096 workers up front (Linux) for a sweep of 4 runs: the machine
    ran out of memory. The pool is as large as the runs, and over the cores it says so."""
    from typer.testing import CliRunner

    from sonarmap.pipeline.cli import app

    args = ["sweep", *map(str, toy_env), "--set", "count.bins=3,5"]
    args += ["--store", str(tmp_path / "s"), "--out", str(tmp_path / "o"), "-j", "4096"]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    runs = 2 * len(toy_env)
    assert f"{runs} runs on local with {runs} job(s)" in res.stderr
    assert ("runs at a time on" in res.stderr) == (runs > (os.cpu_count() or 1))
