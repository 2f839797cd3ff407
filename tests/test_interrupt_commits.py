"""Ctrl-C while a stage computes in the run's own process (campaign 14 #2, #4 and #6): a
stage that committed just before the interrupt stays referenced, so `gc` keeps it; the
stage still computing leaves no temporary folder and can no longer commit; a run left on
another thread gives up its lease."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from test_engine_cache import run_toy

import sonarmap.pipeline.engine.run.runner as runner_module
from sonarmap.pipeline.engine.run.abandon import abandon_open_runs
from sonarmap.pipeline.engine.run.runner import RunResult
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
from sonarmap.pipeline.engine.store.commit_gate import CommitGate, GateClosed


@pytest.fixture
def data(tmp_path: Path) -> Path:
    path = tmp_path / "raw.bin"
    path.write_bytes(bytes(range(256)) * 4)
    return path


def _run_two_workers(dataset: Path, store: Path) -> RunResult:
    """The toy pipeline with two stages at a time: the one computed in this process runs
    on a thread, as in `run -j 2`, and goes on after the interrupt."""
    return run_toy(dataset, store, workers=2)


def _interrupt_when(monkeypatch: pytest.MonkeyPatch, ready: Callable[[], bool]) -> None:
    """Ctrl-C reaches the runner's thread on its first wake-up after `ready()` holds: the
    moment between a stage thread's work and the runner's own bookkeeping."""
    real_wait = runner_module.wait

    def wait(futures: Any, **kwargs: Any) -> Any:
        deadline = time.monotonic() + 30
        while not ready() and time.monotonic() < deadline:
            found = real_wait(futures, timeout=0.01, **kwargs)
            if found[0] and not ready():
                return found
        raise KeyboardInterrupt

    monkeypatch.setattr(runner_module, "wait", wait)


def _committed(store: Path, stage: str) -> list[Path]:
    return sorted(store.glob(f"{stage}/*/manifest.json"))


def test_a_stage_committed_just_before_ctrl_c_stays_in_the_record_and_through_gc(
    data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store = tmp_path / "store"
    _interrupt_when(monkeypatch, lambda: bool(_committed(store, "double")))
    with pytest.raises(KeyboardInterrupt):
        _run_two_workers(data, store)
    (manifest,) = _committed(store, "double")
    report = ArtifactStore(store).gc()
    assert report["removed"] == []  # was: double/<key>, committed work deleted
    assert manifest.exists()
    assert not any((store / ".tmp").iterdir())
    monkeypatch.undo()
    assert {r.stage for r in run_toy(data, store).stages if r.status == "hit"} >= {
        "source",
        "double",
    }


def test_a_stage_computing_at_ctrl_c_leaves_no_folder_and_never_commits(
    data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store, calls, gate = tmp_path / "store", tmp_path / "calls.log", tmp_path / "gate"
    monkeypatch.setenv("TOY_CALL_LOG", str(calls))
    monkeypatch.setenv("TOY_GATE", str(gate))  # `double` waits for this file
    _interrupt_when(monkeypatch, lambda: calls.exists() and "double" in calls.read_text())
    threads = threading.active_count()
    with pytest.raises(KeyboardInterrupt):
        _run_two_workers(data, store)
    assert not any((store / ".tmp").iterdir())  # was: double-<key>-<pid>-<hex>
    gate.touch()  # the abandoned stage finishes its work now
    deadline = time.monotonic() + 30
    while threading.active_count() > threads and time.monotonic() < deadline:
        time.sleep(0.01)
    assert threading.active_count() == threads
    assert _committed(store, "double") == []  # its commit was refused
    assert not any((store / ".tmp").iterdir())


def test_the_gate_lets_a_commit_in_progress_finish_and_reports_it() -> None:
    gate = CommitGate()
    started, release = threading.Event(), threading.Event()
    closed: list[Any] = []

    def commit() -> None:
        with gate.committing("double", "k" * 64):
            started.set()
            release.wait(10)

    thread = threading.Thread(target=commit)
    thread.start()
    started.wait(10)
    closer = threading.Thread(target=lambda: closed.append(gate.close()))
    closer.start()
    time.sleep(0.05)
    assert not closed  # close() waits for the commit in progress
    release.set()
    thread.join(10)
    closer.join(10)
    assert closed == [([("double", "k" * 64)], [])]
    with pytest.raises(GateClosed), gate.committing("count", "c" * 64):
        pass


def test_a_run_left_on_another_thread_is_closed_by_the_interrupted_command(
    data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`follow`'s map update runs on a thread that Ctrl-C does not unwind: its lease and
    its stage's folder stayed in the store until `gc` (campaign 14 #4)."""
    store, calls, gate = tmp_path / "store", tmp_path / "calls.log", tmp_path / "gate"
    monkeypatch.setenv("TOY_CALL_LOG", str(calls))
    monkeypatch.setenv("TOY_GATE", str(gate))
    errors: list[BaseException] = []

    def update() -> None:
        try:
            run_toy(data, store)
        except BaseException as err:
            errors.append(err)

    thread = threading.Thread(target=update, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not (calls.exists() and "double" in calls.read_text()) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert list((store / ".leases").glob("*.json")) and any((store / ".tmp").iterdir())
    assert abandon_open_runs() == 2  # the run's commit gate and its lease
    assert not list((store / ".leases").iterdir())
    assert not any((store / ".tmp").iterdir())
    gate.touch()
    thread.join(30)
    assert len(errors) == 1  # its commit refused, or its folder gone under it
    assert _committed(store, "double") == [] and _committed(store, "source")
    record = json.loads(next((store / "runs").glob("*.json")).read_text())
    assert set(record["stages"]) == {"source"}  # kept by gc
    assert ArtifactStore(store).gc()["removed"] == []


def test_ctrl_c_after_the_last_commit_keeps_the_last_stage(
    data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The last stage's commit is recorded by the run's final record: Ctrl-C just before
    it left that stage out, and `gc` deleted it (campaign 14 #2, 5 of 5 with -j 2)."""
    store = tmp_path / "store"
    real_record = runner_module.record_run

    def record_run(*args: Any, done: Any = None) -> None:
        if done is None:  # the final record, after every commit
            raise KeyboardInterrupt
        real_record(*args, done=done)

    monkeypatch.setattr(runner_module, "record_run", record_run)
    with pytest.raises(KeyboardInterrupt):
        _run_two_workers(data, store)
    record = json.loads(next((store / "runs").glob("*.json")).read_text())
    assert set(record["stages"]) == {"source", "double", "summary", "count"}
    assert ArtifactStore(store).gc()["removed"] == []
