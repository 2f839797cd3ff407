"""The caching contract, in the style of Hamilton's cache tests (did / did_not)."""

from __future__ import annotations

import os
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import toy_stages
from toy_stages import TOY_STAGES

from sonarmap.pipeline.engine.errors import ConfigError, StageFailed
from sonarmap.pipeline.engine.run.runner import RunResult, execute, plan
from sonarmap.pipeline.engine.run.session import make_context
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
from sonarmap.stages.base import Input, Output, Stage


def _dataset(tmp_path: Path, content: bytes = bytes(range(256)) * 4) -> Path:
    path = tmp_path / "raw.bin"
    path.write_bytes(content)
    return path


def run_toy(
    dataset: Path,
    store: Path,
    overrides: tuple[str, ...] = (),
    *,
    stages: tuple[Stage, ...] = TOY_STAGES,
    force: tuple[str, ...] = (),
    until: str | None = None,
    workers: int = 1,
) -> RunResult:
    ctx = make_context(
        dataset,
        stages=stages,
        overrides=overrides,
        store_dir=store,
        parts=lambda p: [p],
        opener=lambda _section: dataset.read_bytes(),
    )
    planned = plan(ctx.stages, ctx.config, ctx.dataset, ctx.store, force=force, until=until)
    return execute(planned, ctx.config, ctx.dataset, ctx.store, workers=workers)


def did(result: RunResult) -> set[str]:
    return {r.stage for r in result.stages if r.status == "computed"}


def did_not(result: RunResult) -> set[str]:
    return {r.stage for r in result.stages if r.status == "hit"}


@pytest.fixture(autouse=True)
def _reset_calls() -> None:
    toy_stages.CALLS.clear()


def test_rerun_with_nothing_changed_same_result_dont_recompute(tmp_path: Path) -> None:
    data, store = _dataset(tmp_path), tmp_path / "store"
    first = run_toy(data, store)
    assert did(first) == {"source", "double", "summary", "count"}
    toy_stages.CALLS.clear()
    second = run_toy(data, store)
    assert did(second) == set()
    assert did_not(second) == {"source", "double", "summary", "count"}
    assert sum(toy_stages.CALLS.values()) == 0
    assert [r.key for r in first.stages] == [r.key for r in second.stages]


def test_changing_one_section_recomputes_it_and_downstream_only(tmp_path: Path) -> None:
    data, store = _dataset(tmp_path), tmp_path / "store"
    run_toy(data, store)
    changed = run_toy(data, store, ("double.factor=3",))
    assert did(changed) == {"double", "summary"}
    assert did_not(changed) == {"source", "count"}
    reasons = {r.stage: r.reason for r in changed.stages}
    assert reasons["double"] == "config changed: double.factor 2 -> 3"
    assert reasons["summary"] == "upstream double recomputed"


def test_changing_an_unrelated_section_recomputes_nothing_upstream(tmp_path: Path) -> None:
    data, store = _dataset(tmp_path), tmp_path / "store"
    run_toy(data, store)
    changed = run_toy(data, store, ("count.bins=8",))
    assert did(changed) == {"count"}
    root_changed = run_toy(data, store, ("source.scale=2.0",))
    assert did(root_changed) == {"source", "double", "summary", "count"}


def test_bumping_a_stage_version_recomputes_it_and_downstream(tmp_path: Path) -> None:
    data, store = _dataset(tmp_path), tmp_path / "store"
    run_toy(data, store)
    double_v2 = Stage(
        "double",
        2,
        toy_stages.DoubleConfig,
        toy_stages.DOUBLE.inputs,
        toy_stages.DOUBLE.outputs,
        toy_stages.DOUBLE.run,
    )
    stages = (toy_stages.SOURCE, double_v2, toy_stages.SUMMARY, toy_stages.COUNT)
    result = run_toy(data, store, stages=stages)
    assert did(result) == {"double", "summary"}
    assert {r.stage: r.reason for r in result.stages}["double"] == "version 1 -> 2"


def test_dataset_content_change_recomputes_everything(tmp_path: Path) -> None:
    data, store = _dataset(tmp_path), tmp_path / "store"
    run_toy(data, store)
    data.write_bytes(bytes(reversed(range(256))) * 4)
    result = run_toy(data, store)
    assert did(result) == {"source", "double", "summary", "count"}


def test_same_size_rewrite_with_its_old_mtime_restored_recomputes(tmp_path: Path) -> None:
    """The fingerprint memo is keyed by stat identity: `cp -p` / `rsync -t` style rewrites
    in place keep size, mtime and inode, and must still not reuse the old digest."""
    data, store = _dataset(tmp_path), tmp_path / "store"
    run_toy(data, store)
    before = data.stat()
    data.write_bytes(bytes(reversed(range(256))) * 4)  # same size, same inode
    os.utime(data, ns=(before.st_atime_ns, before.st_mtime_ns))
    after = data.stat()
    assert (after.st_size, after.st_mtime_ns, after.st_ino) == (
        before.st_size,
        before.st_mtime_ns,
        before.st_ino,
    )
    result = run_toy(data, store)
    assert did(result) == {"source", "double", "summary", "count"}


def test_forced_stage_recomputes_but_downstream_keys_stay(tmp_path: Path) -> None:
    data, store = _dataset(tmp_path), tmp_path / "store"
    run_toy(data, store)
    result = run_toy(data, store, force=("double",))
    assert did(result) == {"double"}
    assert {r.stage: r.reason for r in result.stages}["double"] == "forced"


def test_until_stops_after_the_named_stage(tmp_path: Path) -> None:
    data, store = _dataset(tmp_path), tmp_path / "store"
    result = run_toy(data, store, until="double")
    assert [r.stage for r in result.stages] == ["source", "double"]


def test_failing_stage_leaves_no_artifact_and_next_run_recomputes(tmp_path: Path) -> None:
    data, store = _dataset(tmp_path), tmp_path / "store"
    with pytest.raises(StageFailed, match="stage summary failed: RuntimeError"):
        run_toy(data, store, ("summary.fail=true",))
    assert not any(r.stage == "summary" for r in ArtifactStore(store).iter_artifacts())
    assert not list((store / ".tmp").iterdir())
    toy_stages.CALLS.clear()
    result = run_toy(data, store)
    assert did(result) == {"summary", "count"}
    assert toy_stages.CALLS["source"] == 0


def test_unknown_override_names_closest_key(tmp_path: Path) -> None:
    data, store = _dataset(tmp_path), tmp_path / "store"
    with pytest.raises(ConfigError, match=r"unknown key 'double\.factr'.*'double\.factor'"):
        run_toy(data, store, ("double.factr=3",))
    with pytest.raises(ConfigError, match=r"double\.factor"):
        run_toy(data, store, ("double.factor=abc",))


def test_determinism_two_fresh_stores_byte_identical_parquet(tmp_path: Path) -> None:
    data = _dataset(tmp_path)
    a = run_toy(data, tmp_path / "a")
    b = run_toy(data, tmp_path / "b")
    for ra, rb in zip(a.stages, b.stages, strict=True):
        assert ra.key == rb.key
        for f in sorted(Path(ra.path).iterdir()):
            if f.name == "manifest.json":
                continue
            assert f.read_bytes() == (Path(rb.path) / f.name).read_bytes(), f.name
    table = pq.read_table(Path(a.stages[1].path) / "d.parquet")
    assert table.num_rows == 50


def test_verify_detects_tampering(tmp_path: Path) -> None:
    from sonarmap.pipeline.engine.errors import ArtifactCorrupt

    data, store_dir = _dataset(tmp_path), tmp_path / "store"
    result = run_toy(data, store_dir)
    store = ArtifactStore(store_dir)
    ref = store.get("double", result.stages[1].key)
    assert ref is not None
    store.verify(ref)
    blob = ref.path / "d.bin"
    raw = blob.read_bytes()
    blob.write_bytes(bytes([raw[0] ^ 0xFF]) + raw[1:])
    with pytest.raises(ArtifactCorrupt, match="sha256"):
        store.verify(ref)


def test_gc_removes_unreferenced_artifacts_only(tmp_path: Path) -> None:
    data, store_dir = _dataset(tmp_path), tmp_path / "store"
    run_toy(data, store_dir)
    run_toy(data, store_dir, ("count.bins=8",))
    store = ArtifactStore(store_dir)
    assert sum(r.stage == "count" for r in store.iter_artifacts()) == 2
    # Both runs are recorded, so nothing is garbage yet.
    assert store.gc()["removed"] == []
    for f in (store_dir / "runs").glob("*.json"):
        f.unlink()
    run_toy(data, store_dir, ("count.bins=8",))
    report = store.gc()
    assert report["removed"] and all(r.startswith("count/") for r in report["removed"])
    assert sum(r.stage == "count" for r in store.iter_artifacts()) == 1


def test_a_miss_names_the_upstream_whose_artifact_changed_even_when_it_is_a_hit(
    tmp_path: Path,
) -> None:
    """`both` last ran on double's old artifact; double was recomputed since by a run
    that stopped before `both` (`--until`), so double is a hit now, and both's reason
    must still name double, not every stage it reads."""
    both = Stage(
        "both",
        1,
        toy_stages.SummaryConfig,
        (Input("double", "table"), Input("count", "hist")),
        (Output("summary", "json", "s.json"),),
        lambda _config, inputs: {"summary": {"rows": inputs["double.table"].num_rows}},
    )
    stages = (*TOY_STAGES, both)
    data, store = _dataset(tmp_path), tmp_path / "store"
    run_toy(data, store, stages=stages)
    run_toy(data, store, ("double.factor=3",), stages=stages, until="double")
    ctx = make_context(
        data,
        stages=stages,
        overrides=("double.factor=3",),
        store_dir=store,
        parts=lambda p: [p],
        opener=lambda _section: data.read_bytes(),
    )
    planned = {p.stage.name: p for p in plan(ctx.stages, ctx.config, ctx.dataset, ctx.store)}
    assert planned["double"].hit and planned["count"].hit
    assert planned["both"].reason == "upstream double recomputed"
