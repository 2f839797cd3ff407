"""The graph runner: independent stages side by side, the same artifacts as one at a time."""

from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path

import pytest
from toy_stages import GRAPH, TOY_STAGES

from sonarmap.pipeline.engine.errors import StageFailed
from sonarmap.pipeline.engine.run.runner import RunResult, execute, plan
from sonarmap.pipeline.engine.run.session import make_context
from sonarmap.stages.base import Stage

_VOLATILE = ("build_seconds", "created_at", "dataset_path")
"""Manifest fields that name when and where, not what, a stage computed."""


def _run(
    tmp_path: Path,
    store: Path,
    workers: int,
    overrides: tuple[str, ...] = (),
    stages: tuple[Stage, ...] = TOY_STAGES,
) -> RunResult:
    dataset = tmp_path / "raw.bin"
    if not dataset.exists():
        dataset.write_bytes(bytes(range(256)) * 4)
    ctx = make_context(
        dataset,
        stages=stages,
        overrides=overrides,
        store_dir=store,
        parts=GRAPH.parts,
        opener=lambda section: GRAPH.open(dataset, section),
    )
    planned = plan(ctx.stages, ctx.config, ctx.dataset, ctx.store)
    return execute(planned, ctx.config, ctx.dataset, ctx.store, workers=workers)


def _contents(store: Path) -> dict[str, object]:
    """Every artifact's files (bytes) and manifest (less its volatile fields), by path."""
    found: dict[str, object] = {}
    for stage in (s.name for s in TOY_STAGES):
        for path in sorted((store / stage).rglob("*")):
            if not path.is_file():
                continue
            name = path.relative_to(store).as_posix()
            if path.name == "manifest.json":
                doc = json.loads(path.read_text())
                found[name] = {k: v for k, v in doc.items() if k not in _VOLATILE}
            else:
                found[name] = path.read_bytes()
    return found


def test_two_workers_give_the_store_one_worker_gives(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    log = tmp_path / "calls.log"
    monkeypatch.setenv("TOY_CALL_LOG", str(log))
    # double still runs when count starts: 3 s covers a second worker process starting on a
    # loaded machine (with 1 s, one worker once ran both while the other was still importing)
    slow = ("double.sleep_s=3",)
    serial = _run(tmp_path, tmp_path / "one", workers=1, overrides=slow)
    parallel = _run(tmp_path, tmp_path / "two", workers=2, overrides=slow)
    contents = _contents(tmp_path / "one")
    assert len(contents) == 2 * len(TOY_STAGES) + 1  # manifests, files (double has two)
    assert _contents(tmp_path / "two") == contents
    assert [r.stage for r in parallel.stages] == [r.stage for r in serial.stages]
    assert [r.key for r in parallel.stages] == [r.key for r in serial.stages]
    assert {r.status for r in parallel.stages} == {"computed"}
    # double and count both read only source: with two workers they ran in two processes.
    calls = [line.split() for line in log.read_text().splitlines()]
    pids = {name: pid for name, pid in calls[len(TOY_STAGES) :]}
    assert pids["double"] != pids["count"]


def test_a_failing_stage_stops_the_run_and_the_others_commit(tmp_path: Path) -> None:
    store = tmp_path / "store"
    with pytest.raises(StageFailed, match="stage summary failed: RuntimeError"):
        _run(tmp_path, store, workers=2, overrides=("summary.fail=true",))
    # count ran beside the failing branch and was committed; summary left nothing.
    assert len(list((store / "count").glob("*/manifest.json"))) == 1
    assert not (store / "summary").exists() or not list((store / "summary").iterdir())
    again = _run(tmp_path, store, workers=2)
    status = {r.stage: r.status for r in again.stages}
    assert status == {"source": "hit", "double": "hit", "summary": "computed", "count": "hit"}


def test_a_cached_run_starts_no_worker_process(tmp_path: Path) -> None:
    store = tmp_path / "store"
    _run(tmp_path, store, workers=2)
    import multiprocessing

    before = len(multiprocessing.active_children())
    again = _run(tmp_path, store, workers=2)
    assert {r.status for r in again.stages} == {"hit"}
    assert len(multiprocessing.active_children()) == before


def test_a_stage_off_the_critical_path_takes_a_worker_process(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Like the figures: the slot in the runner's process stays for the other stages."""
    log = tmp_path / "calls.log"
    monkeypatch.setenv("TOY_CALL_LOG", str(log))
    stages = tuple(
        replace(s, off_critical_path=True) if s.name == "double" else s for s in TOY_STAGES
    )
    result = _run(tmp_path, tmp_path / "store", workers=2, stages=stages)
    assert {r.status for r in result.stages} == {"computed"}
    pids = dict(line.split() for line in log.read_text().splitlines())
    assert pids["double"] != str(os.getpid())
    assert pids["count"] == str(os.getpid())
    # One worker: everything here, as the serial runner always did.
    log.unlink()
    _run(tmp_path, tmp_path / "serial", workers=1, stages=stages)
    assert {pid for _, pid in (line.split() for line in log.read_text().splitlines())} == {
        str(os.getpid())
    }
