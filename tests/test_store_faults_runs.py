"""Store faults around run records: unique run ids, gc reachability, truthful `--json`."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from test_engine_cache import run_toy
from toy_stages import SOURCE, CountConfig

from sonarmap.pipeline.engine.run.runner import execute, plan
from sonarmap.pipeline.engine.run.session import make_context
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
from sonarmap.stages.base import Output, Stage

TESTS = Path(__file__).resolve().parent


def _pool(_config: CountConfig, inputs: dict[str, Any]) -> dict[str, Any]:
    v = inputs["source_0.table"].column("v").to_numpy()
    return {"pooled": pa.table({"total": np.array([v.sum()], dtype=np.float64)})}


# Like `train`: reads another run's artifact bound under another name.
POOL = Stage("pool", 1, CountConfig, ("source_0.table",), (Output("pooled", "parquet", "p.parquet"),), _pool)  # fmt: skip


def _train_like(data: Path, store: Path) -> None:
    """What `training.train_on` does: upstream stages per dataset, then one stage over all."""
    ctx = make_context(data, stages=(SOURCE,), config_stages=(SOURCE, POOL), store_dir=store,
                       parts=lambda p: [p], opener=lambda _s: data.read_bytes())  # fmt: skip
    upstream = execute(plan(ctx.stages, ctx.config, ctx.dataset, ctx.store), ctx.config,
                       ctx.dataset, ctx.store)  # fmt: skip
    external = {"source_0": (SOURCE, upstream.artifacts["source"])}
    planned = plan((POOL,), ctx.config, ctx.dataset, ctx.store, external=external)
    execute(planned, ctx.config, ctx.dataset, ctx.store, external=external)


def test_a_stage_over_other_runs_artifacts_gets_its_own_record(tmp_path: Path) -> None:
    data = tmp_path / "raw.bin"
    data.write_bytes(bytes(range(256)) * 4)
    store_dir = tmp_path / "store"
    _train_like(data, store_dir)
    store = ArtifactStore(store_dir)
    recorded = sorted(sorted(r["stages"]) for r in store.run_records())
    assert recorded == [["pool"], ["source"]]
    assert store.gc()["removed"] == []
    assert {r.stage for r in store.iter_artifacts()} == {"source", "pool"}


def test_gc_keeps_everything_upstream_of_a_kept_artifact(tmp_path: Path) -> None:
    data = tmp_path / "raw.bin"
    data.write_bytes(bytes(range(256)) * 4)
    store_dir = tmp_path / "store"
    _train_like(data, store_dir)
    run_toy(data, store_dir, ("count.bins=8",))
    store = ArtifactStore(store_dir)
    # Only the `pool` record is left: its input (source) must survive, the rest goes.
    for f in (store_dir / "runs").glob("*.json"):
        if "pool" not in json.loads(f.read_text())["stages"]:
            f.unlink()
    report = store.gc()
    assert sorted(a.split("/")[0] for a in report["removed"]) == ["count", "double", "summary"]
    assert {r.stage for r in store.iter_artifacts()} == {"source", "pool"}


def _cli(data: Path, store: Path, env: dict[str, str], stderr: Any) -> subprocess.Popen[bytes]:
    cmd = [sys.executable, "-m", "sonarmap.pipeline", "-v", "run", str(data), "--store", str(store),
           "--json", "-q"]  # fmt: skip
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=stderr)


def _wait_for(path: Path, text: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text():
            return
        time.sleep(0.02)
    raise AssertionError(f"{text!r} never appeared in {path}")


def test_concurrent_runs_json_says_who_computed_and_who_reused(tmp_path: Path) -> None:
    data = tmp_path / "raw.bin"
    data.write_bytes(bytes(range(256)) * 4)
    store, calls, gate = tmp_path / "store", tmp_path / "calls.log", tmp_path / "gate"
    env = dict(os.environ, SONARMAP_GRAPH="toy_stages:GRAPH", TOY_CALL_LOG=str(calls),
               TOY_GATE=str(gate), PYTHONPATH=os.pathsep.join([str(TESTS), str(TESTS.parent)]))  # fmt: skip
    logs = [tmp_path / "a.err", tmp_path / "b.err"]
    with logs[0].open("wb") as a_err, logs[1].open("wb") as b_err:
        first = _cli(data, store, env, a_err)
        _wait_for(calls, "double")  # the first run now holds double's lock
        second = _cli(data, store, env, b_err)
        _wait_for(logs[1], "computing double")  # the second now waits on that lock
        gate.touch()
        outs = [p.communicate(timeout=120)[0] for p in (first, second)]
    assert [p.returncode for p in (first, second)] == [0, 0], [f.read_text() for f in logs]
    a, b = ({s["stage"]: s["status"] for s in json.loads(o)["stages"]} for o in outs)
    assert a["source"] == a["double"] == "computed"
    assert b["source"] == "hit" and b["double"] == "reused"
    # After the lock is released both race for the rest: one computes, the other reuses.
    for stage in ("summary", "count"):
        assert sorted((a[stage], b[stage])) in (["computed", "reused"], ["computed", "hit"])
    # Whatever each run says it computed is exactly what ran, once per stage.
    ran = sorted(line.split()[0] for line in calls.read_text().splitlines())
    said = sorted(s for doc in (a, b) for s, status in doc.items() if status == "computed")
    assert ran == said
    # Both runs share one identity (dataset, config, stages), hence one complete record.
    (record,) = ArtifactStore(store).run_records()
    assert sorted(record["stages"]) == sorted(a)
    assert not list((store / "runs").glob(".*.tmp"))
