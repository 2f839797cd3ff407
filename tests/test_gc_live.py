"""Live and interrupted runs against `gc`, disk faults during `run`, refused model files,
and the run-level guard against empty maps."""

from __future__ import annotations

import errno
import io
import json
import os
import pickle
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import torch
from click.testing import Result
from test_engine_cache import run_toy
from typer.testing import CliRunner

import sonarmap.pipeline.engine.store.artifact_store
import sonarmap.pipeline.engine.store.gc
from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.errors import PipelineError, StageFailed
from sonarmap.pipeline.engine.run import output_checks
from sonarmap.pipeline.engine.run.output_checks import OutputCheck, check_stage
from sonarmap.pipeline.engine.run.runner import execute, plan
from sonarmap.pipeline.engine.run.session import make_context
from sonarmap.pipeline.engine.store.artifact import ArtifactRef
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
from sonarmap.pipeline.engine.store.leases import RunLease
from sonarmap.stages.base import Output, Stage, StageConfig
from sonarmap.stages.classify.stage import STAGE as CLASSIFY
from tests.fixtures.signals import default_sigint

runner = CliRunner()


def cli(*args: object) -> Result:
    return runner.invoke(app, [str(a) for a in args])


def _wait_for(path: Path, text: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text():
            return
        time.sleep(0.01)
    raise AssertionError(f"{text!r} never appeared in {path}")


def _addresses(store: Path) -> set[str]:
    return {f"{r.stage}/{r.key}" for r in ArtifactStore(store).iter_artifacts()}


def _orphans(data: Path, store: Path) -> set[str]:
    """Artifacts no run record names (another config's run, its record deleted)."""
    before = _addresses(store)
    run_toy(data, store, ("source.scale=3",))
    for record in (store / "runs").glob("*.json"):
        record.unlink()
    return _addresses(store) - before


@pytest.fixture
def data(tmp_path: Path) -> Path:
    path = tmp_path / "raw.bin"
    path.write_bytes(bytes(range(256)) * 4)
    return path


@pytest.fixture
def gated(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[Path, Path]:
    """(call log, gate): the toy `double` stage blocks until the gate file exists."""
    calls, gate = tmp_path / "calls.log", tmp_path / "gate"
    monkeypatch.setenv("TOY_CALL_LOG", str(calls))
    monkeypatch.setenv("TOY_GATE", str(gate))
    return calls, gate


# -- 1. gc never touches a live run ---------------------------------------------------------


def test_gc_during_a_live_run_keeps_its_artifacts_and_the_run_succeeds(
    data: Path, tmp_path: Path, gated: tuple[Path, Path]
) -> None:
    store = tmp_path / "store"
    calls, gate = gated
    gate.touch()
    orphans = _orphans(data, store)
    gate.unlink()
    calls.unlink()
    errors: list[BaseException] = []

    def run() -> None:
        try:
            run_toy(data, store)
        except BaseException as err:  # reported by the main thread
            errors.append(err)

    thread = threading.Thread(target=run)
    thread.start()
    try:
        _wait_for(calls, "double")  # `source` is committed; `double` is computing
        report = ArtifactStore(store).gc()
    finally:
        gate.touch()
        thread.join(timeout=60)
    assert not errors, errors
    assert report["live_runs"] == 1
    assert set(report["removed"]) == orphans  # gc still collects what nobody uses
    (source,) = [a for a in _addresses(store) if a.startswith("source/")]
    assert source not in report["removed"]
    live = ArtifactStore(store)
    assert {r.stage for r in live.iter_artifacts()} == {"source", "double", "summary", "count"}
    for ref in live.iter_artifacts():
        live.verify(ref)
    after = live.gc()
    assert after["removed"] == [] and after["live_runs"] == 0
    assert not list((store / ".leases").iterdir())


def test_killed_run_keeps_its_finished_stages_and_its_lease_goes_stale(
    data: Path, tmp_path: Path, gated: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    store = tmp_path / "store"
    calls, _gate = gated
    pid = os.fork()
    if pid == 0:  # the child blocks in `double` until killed
        try:
            run_toy(data, store)
        finally:
            os._exit(3)
    try:
        _wait_for(calls, "double")
        while_alive = ArtifactStore(store).gc()  # another process's lease: flock held
        assert while_alive["live_runs"] == 1 and while_alive["removed"] == []
    finally:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
    report = ArtifactStore(store).gc()
    assert report["live_runs"] == 0 and report["stale_leases"] == 1
    assert report["removed"] == [] and report["tmp_removed"] == 1  # double's commit
    assert {r.stage for r in ArtifactStore(store).iter_artifacts()} == {"source"}
    assert not list((store / ".leases").iterdir()) and not list((store / ".tmp").iterdir())
    monkeypatch.delenv("TOY_GATE")
    statuses = {r.stage: r.status for r in run_toy(data, store).stages}
    assert statuses["source"] == "hit" and statuses["double"] == "computed"


def _gone(pid: int) -> bool:
    """The process has ended (a zombie no one reaps counts as ended)."""
    try:
        state = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return True
    return "\nState:\tZ" in state


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads /proc")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_a_signalled_run_ends_with_its_worker_and_gc_keeps_its_finished_work(
    data: Path, tmp_path: Path, sig: signal.Signals
) -> None:
    # Both stages after `source` are held: one computes in the run's thread, the other in
    # its worker process, which outlived a SIGTERM or kill -9 of the run (holding its
    # memory and stderr) until it ended the stage itself.
    store, calls = tmp_path / "store", tmp_path / "calls.log"
    env = {
        **os.environ,
        "SONARMAP_GRAPH": "toy_stages:GRAPH",
        "PYTHONPATH": os.pathsep.join([str(Path(__file__).parent), str(Path(__file__).parents[1])]),
        "TOY_CALL_LOG": str(calls),
        "TOY_GATE": str(tmp_path / "gate"),
        "TOY_GATE_STAGES": "double,count",
    }
    args = ["run", str(data), "--store", str(store), "-q", "--workers", "2"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "sonarmap.pipeline", *args],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=default_sigint,
    )
    try:
        _wait_for(calls, "double")
        _wait_for(calls, "count")
        pids = {int(line.split()[1]) for line in calls.read_text().splitlines()}
        assert len(pids) == 2  # the run's own process and its worker
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=20)  # end of stderr: no process of the run holds it
    finally:
        proc.kill()
    assert proc.returncode == (128 + sig if sig == signal.SIGTERM else -sig)
    assert "Traceback" not in err
    deadline = time.monotonic() + 5
    while not all(_gone(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert all(_gone(pid) for pid in pids)
    report = ArtifactStore(store).gc()
    assert report["live_runs"] == 0 and report["removed"] == []
    assert {r.stage for r in ArtifactStore(store).iter_artifacts()} == {"source"}
    assert not list((store / ".leases").glob("*.json")) and not list((store / ".tmp").iterdir())


def test_a_dead_processs_lease_protects_nothing(data: Path, tmp_path: Path) -> None:
    store = tmp_path / "store"
    orphans = _orphans(data, store)
    pid = os.fork()
    if pid == 0:  # claims every orphan, then dies without releasing its lease
        RunLease(store).__enter__().add(orphans)
        os._exit(0)
    os.waitpid(pid, 0)
    assert len(list((store / ".leases").glob("*.json"))) == 1
    report = ArtifactStore(store).gc()
    assert report["stale_leases"] == 1 and report["live_runs"] == 0
    assert set(report["removed"]) == orphans
    assert not list((store / ".leases").iterdir())


def test_a_failed_stage_keeps_the_stages_before_it_through_gc(data: Path, tmp_path: Path) -> None:
    store = tmp_path / "store"
    with pytest.raises(StageFailed):
        run_toy(data, store, ("summary.fail=true",))
    report = ArtifactStore(store).gc()
    assert report["removed"] == []
    assert {r.stage for r in ArtifactStore(store).iter_artifacts()} == {"source", "double"}
    (record,) = ArtifactStore(store).run_records()
    assert record["complete"] is False and sorted(record["stages"]) == ["double", "source"]
    statuses = {r.stage: r.status for r in run_toy(data, store, ("summary.fail=false",)).stages}
    assert statuses["source"] == statuses["double"] == "hit"


@pytest.mark.parametrize("when", ["after the scan", "after gc read the leases"])
def test_a_run_claiming_an_artifact_while_gc_runs_keeps_it(
    data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, when: str
) -> None:
    """A run that starts mid-gc and claims an unreferenced artifact (a cache hit for it)."""
    store = tmp_path / "store"
    orphans = _orphans(data, store)
    claimed = next(a for a in orphans if a.startswith("source/"))
    lease = RunLease(store)
    if when == "after the scan":
        real_scan = ArtifactStore.scan

        def scan(self: ArtifactStore) -> Iterator[Any]:
            yield from real_scan(self)
            if not lease.addresses:
                lease.__enter__().add([claimed])

        monkeypatch.setattr(ArtifactStore, "scan", scan)
    else:
        real_leases = sonarmap.pipeline.engine.store.gc.scan_leases

        def scan_leases(root: Path, *, prune: bool) -> Any:
            found = real_leases(root, prune=prune)
            if not lease.addresses:
                lease.__enter__().add([claimed])
            return found

        monkeypatch.setattr(sonarmap.pipeline.engine.store.gc, "scan_leases", scan_leases)
    try:
        report = ArtifactStore(store).gc()
    finally:
        lease.__exit__(None, None, None)
    assert claimed not in report["removed"]
    assert set(report["removed"]) == orphans - {claimed}
    monkeypatch.undo()
    assert ArtifactStore(store).gc()["removed"] == [claimed]  # lease gone: collected


# -- 2. disk faults during `run` ------------------------------------------------------------


def _one_line_error(res: Result, *needles: str) -> str:
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    (line,) = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert line.startswith("error: ") and len(line) < 400, line
    for needle in needles:
        assert needle in line, (needle, line)
    return line


def test_disk_full_mid_commit_exits_2_and_keeps_what_was_committed(
    toy_cli: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store = tmp_path / "store"
    real_fsync = sonarmap.pipeline.engine.store.artifact_store.fsync_file

    def fsync(path: Path) -> None:
        if path.parent.name.startswith("double-"):  # the second commit, mid-way
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        real_fsync(path)

    monkeypatch.setattr(sonarmap.pipeline.engine.store.artifact_store, "fsync_file", fsync)
    # One worker: count (beside double in the graph) would otherwise commit meanwhile.
    res = cli("run", toy_cli, "--store", store, "-q", "--workers", "1")
    _one_line_error(res, "No space left on device", "(ENOSPC)", ".tmp/double-")
    live = ArtifactStore(store)
    assert {r.stage for r in live.iter_artifacts()} == {"source"}
    for ref in live.iter_artifacts():
        live.verify(ref)
    assert not list((store / ".tmp").iterdir()) and not (store / "double").exists()
    assert live.gc()["removed"] == []  # the committed stage is recorded
    monkeypatch.setattr(sonarmap.pipeline.engine.store.artifact_store, "fsync_file", real_fsync)
    assert cli("run", toy_cli, "--store", store, "-q").exit_code == 0


@pytest.mark.parametrize(
    ("target", "code"),
    [(".cache", errno.EROFS), (".locks", errno.EACCES), (".leases", errno.EROFS)],
)
def test_a_read_only_store_exits_2_naming_the_path(
    toy_cli: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, target: str, code: int
) -> None:
    """Root ignores chmod, so the store's first write into `target` is made to fail."""
    store = tmp_path / "store"
    real_mkdir = Path.mkdir

    def mkdir(self: Path, *args: Any, **kwargs: Any) -> None:
        if self == store / target:
            raise OSError(code, os.strerror(code), str(self))
        real_mkdir(self, *args, **kwargs)

    monkeypatch.setattr(Path, "mkdir", mkdir)
    _one_line_error(cli("run", toy_cli, "--store", store, "-q"), str(store / target))


def test_run_record_on_a_full_disk_exits_2_and_leaves_no_partial_record(
    toy_cli: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store = tmp_path / "store"
    real_write = Path.write_text

    def write_text(self: Path, text: str, *args: Any, **kwargs: Any) -> int:
        if self.parent.name == "runs":
            real_write(self, text[:10], *args, **kwargs)  # a partial write, then the fault
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))
        return real_write(self, text, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", write_text)
    _one_line_error(cli("run", toy_cli, "--store", store, "-q"), "No space left", "/runs/")
    assert not list((store / "runs").iterdir())
    assert {r.stage for r in ArtifactStore(store).iter_artifacts()} == {"source"}


def test_a_store_name_too_long_exits_2_with_the_name_cut_short(
    toy_cli: Path, tmp_path: Path
) -> None:
    store = tmp_path / ("s" * 300)
    line = _one_line_error(cli("run", toy_cli, "--store", store, "-q"), "File name too long")
    assert "…" in line and "s" * 100 not in line


# -- 3. a model.pt that fails to load -------------------------------------------------------


class _Evil:
    marker = ""

    def __reduce__(self) -> tuple[Any, ...]:
        return (os.system, (f"touch {self.marker}",))


def _model_files(marker: Path) -> dict[str, bytes]:
    evil = _Evil()
    evil.marker = str(marker)
    zipped = io.BytesIO()
    torch.save({"state_dict": evil, "class_names": ["a"], "config": {}}, zipped)
    other = io.BytesIO()
    torch.save({"weights": torch.zeros(2)}, other)
    return {
        "malicious zip": zipped.getvalue(),
        "malicious legacy pickle": pickle.dumps(evil, protocol=2),
        "junk": b"PK\x03\x04" + bytes(range(200)),
        "another state dict": other.getvalue(),
    }


def _train_toy(_config: StageConfig, inputs: dict[str, Any]) -> dict[str, Any]:
    return {"model": inputs["dataset"]}


@pytest.mark.parametrize("kind", ["malicious zip", "malicious legacy pickle", "junk",
                                  "another state dict"])  # fmt: skip
def test_a_model_that_is_not_a_weights_only_state_dict_exits_2_naming_it(
    tmp_path: Path, kind: str
) -> None:
    marker = tmp_path / "pwned"
    model = tmp_path / "model.pt"
    model.write_bytes(_model_files(marker)[kind])
    # A toy `train` hands the file to the real classify stage, which loads it first.
    train = Stage("train", 1, StageConfig, ("dataset",), (Output("model", "bytes", "model.pt"),),
                  _train_toy)  # fmt: skip
    classify = Stage("classify", 1, CLASSIFY.config, ("train.model",), CLASSIFY.outputs,
                     CLASSIFY.run)  # fmt: skip
    ctx = make_context(model, stages=(train, classify), store_dir=tmp_path / "store",
                       parts=lambda p: [p], opener=lambda _s: model.read_bytes())  # fmt: skip
    planned = plan(ctx.stages, ctx.config, ctx.dataset, ctx.store)
    with pytest.raises(PipelineError) as info:
        execute(planned, ctx.config, ctx.dataset, ctx.store)
    message = str(info.value)
    assert info.value.exit_code == 2 and "\n" not in message and len(message) < 300
    # The toy `train` reads the file as its dataset: the user's file is named first.
    assert message.startswith(f"{model}: ")
    assert message.endswith(f"(input of stage classify: train/{planned[0].key[:12]}/model.pt)")
    assert "not a weights-only state dict" in message and "weights_only=False" not in message
    assert not marker.exists()  # nothing in the file ran
    assert {r.stage for r in ctx.store.iter_artifacts()} == {"train"}


# -- 4. no empty map in silence -------------------------------------------------------------

TOY_CHECKS = (
    OutputCheck(
        "source",
        lambda r: r.get("source.table", -1) < 2,
        "source: {source.table} rows (fewer than 2)",
    ),
    OutputCheck(
        "double",
        lambda r: r.get("double.table", -1) == 0,
        "no map: double has {double.table} rows",
        fatal=True,
    ),
)


def test_empty_outputs_warn_and_a_run_without_a_map_exits_2_after_committing(
    toy_cli: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(output_checks, "CHECKS", TOY_CHECKS)
    store = tmp_path / "store"
    normal = cli("run", toy_cli, "--store", store, "--json", "-q")
    assert normal.exit_code == 0 and json.loads(normal.stdout)["warnings"] == []
    assert "warning" not in normal.stderr
    one = cli("run", toy_cli, "--store", store, "--json", "-q", "--set", "source.n_rows=1")
    assert one.exit_code == 0, one.output
    assert json.loads(one.stdout)["warnings"] == ["source: 1 rows (fewer than 2)"]
    assert one.stderr.splitlines() == ["warning: source: 1 rows (fewer than 2)"]
    res = cli("run", toy_cli, "--store", store, "-q", "--set", "source.n_rows=0")
    assert res.exit_code == 2, res.output
    lines = res.stderr.splitlines()
    assert lines[0] == "warning: source: 0 rows (fewer than 2)"
    assert lines[1:] == [
        "error: raw.bin: no map: double has 0 rows; first sign: source: 0 rows (fewer than 2)"
    ]
    empty = {r.stage: r for r in ArtifactStore(store).iter_artifacts() if
             r.manifest["outputs"].get("table", {}).get("rows") == 0}  # fmt: skip
    assert sorted(empty) == ["double", "source"]  # committed, and kept by gc
    assert not set(ArtifactStore(store).gc()["removed"]) & {
        f"{r.stage}/{r.key}" for r in empty.values()
    }


def _refs(rows: dict[str, int]) -> dict[str, ArtifactRef]:
    by_stage: dict[str, dict[str, Any]] = {}
    for name, n in rows.items():
        stage, _, output = name.partition(".")
        by_stage.setdefault(stage, {})[output] = {"rows": n}
    return {s: ArtifactRef(s, "0" * 64, Path(s), {"outputs": o}) for s, o in by_stage.items()}


def test_the_pipeline_checks_name_the_collapse_and_stay_silent_on_a_normal_run() -> None:
    normal = {"keyframes.keyframes": 40, "features.features": 41771, "fuse.fused": 9000,
              "slam.poses": 40, "voxelize.map": 12000}  # fmt: skip
    assert all(check_stage(s, _refs(normal)) == [] for s in ("keyframes", "features", "fuse",
                                                               "slam", "voxelize"))  # fmt: skip
    jump = {**normal, "fuse.fused": 0}
    [(message, fatal)] = check_stage("fuse", _refs(jump))
    assert message.startswith("fuse: 0 fused points from 41771 features") and not fatal
    [(message, fatal)] = check_stage("keyframes", _refs({"keyframes.keyframes": 1}))
    assert "1 keyframes" in message and not fatal
    assert check_stage("features", _refs({**normal, "features.features": 0}))
    [(message, fatal)] = check_stage("voxelize", _refs({**jump, "voxelize.map": 0}))
    assert fatal and message.startswith("no map: voxelize's map has 0 points (40 keyframes")


def test_gc_removes_an_abandoned_pull_resume_file_once_stale(tmp_path: Path) -> None:
    from sonarmap.pipeline.engine.store.artifact import PULL_CACHE
    from sonarmap.pipeline.engine.store.gc import collect

    store = ArtifactStore(tmp_path / "store")
    cache = store.root / PULL_CACHE
    cache.mkdir(parents=True)
    fresh, old = cache / ("a" * 64), cache / ("b" * 64)
    fresh.write_bytes(b"x" * 10)
    old.write_bytes(b"y" * 10)
    os.utime(old, (time.time() - 7200, time.time() - 7200))
    report = collect(store, stale_tmp_s=3600.0)
    assert report["tmp_removed"] == 1
    assert fresh.exists() and not old.exists()
