"""Per-keyframe work units (issue 53): a toy stage through the real engine and store, and
the features stage's units with an in-memory memo."""

from __future__ import annotations

import hashlib
import os
import shutil
from collections import Counter
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from sonarmap.pipeline.engine.errors import ArtifactCorrupt
from sonarmap.pipeline.engine.run.runner import RunResult, execute, plan
from sonarmap.pipeline.engine.run.session import make_context
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
from sonarmap.pipeline.engine.store.units import (
    UnitMemo,
    iter_pulled_unit_files,
    iter_unit_files,
    unit_path,
)
from sonarmap.stages.base import DATASET, UNITS_INPUT, Output, Stage, StageConfig

CHUNK = 16
COMPUTED: Counter[str] = Counter()


class ChunksConfig(StageConfig):
    factor: int = 3


def _chunks(config: ChunksConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    """One "keyframe" per 16 bytes of the dataset; each chunk's result a work unit."""
    data = np.frombuffer(inputs["dataset"], np.uint8)
    units = inputs.get(UNITS_INPUT)
    parts = []
    for start in range(0, data.size, CHUNK):
        chunk = data[start : start + CHUNK]
        key = hashlib.sha256(f"chunks/1/{config.factor}/".encode() + chunk.tobytes()).hexdigest()
        got = units.get(key) if units is not None else None
        if got is None:
            COMPUTED["chunks"] += 1
            got = {"v": chunk.astype(np.float64) * config.factor}
            if units is not None:
                units.put(key, got)
        parts.append(np.asarray(got["v"]))
    v = np.concatenate(parts)
    return {"table": pa.table({"i": np.arange(v.size, dtype=np.int64), "v": v})}


STAGES = (
    Stage(
        name="chunks",
        version=1,
        config=ChunksConfig,
        inputs=(DATASET,),
        outputs=(Output("table", "parquet", "table.parquet"),),
        run=_chunks,
        units=True,
    ),
)


def _run(dataset: Path, store: Path, force: tuple[str, ...] = ()) -> RunResult:
    ctx = make_context(
        dataset,
        stages=STAGES,
        overrides=(),
        store_dir=store,
        parts=lambda p: [p],
        opener=lambda _section: dataset.read_bytes(),
    )
    planned = plan(ctx.stages, ctx.config, ctx.dataset, ctx.store, force=force)
    return execute(planned, ctx.config, ctx.dataset, ctx.store)


def _bytes(result: RunResult) -> bytes:
    return (result.artifacts["chunks"].path / "table.parquet").read_bytes()


@pytest.fixture(autouse=True)
def _reset() -> None:
    COMPUTED.clear()


def test_unit_assembled_artifact_equals_cold_and_direct(tmp_path: Path) -> None:
    data = tmp_path / "rec.bin"
    data.write_bytes(bytes(range(200)))
    cold = _run(data, tmp_path / "st")
    cold_bytes = _bytes(cold)
    manifest = cold.artifacts["chunks"].manifest
    assert (manifest["units_reused"], manifest["units_computed"]) == (0, 13)
    assert len(manifest["units"]) == 13
    assert cold.stages[0].units == (0, 13)
    COMPUTED.clear()
    shutil.rmtree(cold.artifacts["chunks"].path)  # the artifact gone, its units kept
    warm = _run(data, tmp_path / "st")
    assert COMPUTED["chunks"] == 0 and warm.artifacts["chunks"].manifest["units_reused"] == 13
    assert _bytes(warm) == cold_bytes
    # `--force` recomputes from scratch, the units too (a repair must not reuse them).
    COMPUTED.clear()
    forced = _run(data, tmp_path / "st", force=("chunks",))
    assert COMPUTED["chunks"] == 13 and forced.artifacts["chunks"].manifest["units_reused"] == 0
    assert _bytes(forced) == cold_bytes
    fresh = _run(data, tmp_path / "other")  # a fresh store: computed whole, same bytes
    assert _bytes(fresh) == cold_bytes
    direct = _chunks(ChunksConfig(), {"dataset": data.read_bytes()})["table"]
    assert direct.equals(pq.read_table(cold.artifacts["chunks"].path / "table.parquet"))


def test_extended_and_trimmed_recordings_reuse_the_units(tmp_path: Path) -> None:
    base = bytes(range(160))
    data = tmp_path / "rec.bin"
    data.write_bytes(base)
    _run(data, tmp_path / "st")
    COMPUTED.clear()
    data.write_bytes(base + bytes(range(100, 132)))  # two more chunks
    longer = _run(data, tmp_path / "st").artifacts["chunks"].manifest
    assert (longer["units_reused"], longer["units_computed"], COMPUTED["chunks"]) == (10, 2, 2)
    COMPUTED.clear()
    data.write_bytes(base[:128])  # trimmed to 8 chunks
    shorter = _run(data, tmp_path / "st").artifacts["chunks"].manifest
    assert (shorter["units_reused"], shorter["units_computed"], COMPUTED["chunks"]) == (8, 0, 0)


def test_gc_keeps_listed_units_and_drops_orphans(tmp_path: Path) -> None:
    data = tmp_path / "rec.bin"
    data.write_bytes(bytes(range(64)))
    result = _run(data, tmp_path / "st")
    store = ArtifactStore(tmp_path / "st")
    orphan = UnitMemo(store.root, "chunks")
    orphan.put("ab" * 32, {"v": np.zeros(3)})
    old = unit_path(store.root, "chunks", "ab" * 32)
    os.utime(old, ns=(1, 1))
    report = store.gc()
    assert report["units_removed"] == 1 and not old.exists()
    listed = set(result.artifacts["chunks"].manifest["units"])
    assert {key for _, key, _ in iter_unit_files(store.root)} == listed
    assert not report["removed"]  # the store scan does not take units/ for a stage


def test_tampered_unit_fails_verify_and_is_recomputed_locally(tmp_path: Path) -> None:
    data = tmp_path / "rec.bin"
    data.write_bytes(bytes(range(64)))
    cold = _run(data, tmp_path / "st")
    store = ArtifactStore(tmp_path / "st")
    key = sorted(cold.artifacts["chunks"].manifest["units"])[0]
    path = unit_path(store.root, "chunks", key)
    raw = bytearray(path.read_bytes())
    raw[-1] ^= 0xFF
    path.write_bytes(bytes(raw))
    with pytest.raises(ArtifactCorrupt, match="unit chunks/"):
        store.verify(cold.artifacts["chunks"])
    COMPUTED.clear()
    shutil.rmtree(cold.artifacts["chunks"].path)  # as `gc --broken` does
    again = _run(data, tmp_path / "st")
    manifest = again.artifacts["chunks"].manifest
    assert (manifest["units_reused"], manifest["units_computed"], COMPUTED["chunks"]) == (3, 1, 1)
    assert any("altered on disk, recomputed" in w for w in again.warnings)
    assert _bytes(again) == _bytes(cold)
    store.verify(again.artifacts["chunks"])  # the recomputed unit replaced the altered one


def test_another_units_file_in_a_units_place_is_recomputed(tmp_path: Path) -> None:
    """A valid unit file copied over another key's passed its own digest and was reused:
    the extension's artifact then held the wrong chunk and verified clean (campaign 11)."""
    data = tmp_path / "rec.bin"
    data.write_bytes(bytes(range(64)))
    cold = _run(data, tmp_path / "st")
    store = ArtifactStore(tmp_path / "st")
    first, second = sorted(cold.artifacts["chunks"].manifest["units"])[:2]
    shutil.copyfile(unit_path(store.root, "chunks", first), unit_path(store.root, "chunks", second))
    shutil.rmtree(cold.artifacts["chunks"].path)
    COMPUTED.clear()
    again = _run(data, tmp_path / "st")
    assert COMPUTED["chunks"] == 1
    assert any("another unit's file" in w for w in again.warnings), again.warnings
    assert _bytes(again) == _bytes(cold)


def test_a_copied_artifact_brings_its_units_and_a_missing_one_is_refused(tmp_path: Path) -> None:
    """The model cache's copy into a run's store (`copy_verified`) carries the units its
    manifest lists; `verify` reads the units of the store holding the artifact (a push takes
    upstream artifacts from the model cache)."""
    from sonarmap.pipeline.training.model_cache import copy_verified

    data = tmp_path / "rec.bin"
    data.write_bytes(bytes(range(64)))
    ref = _run(data, tmp_path / "cache").artifacts["chunks"]
    ArtifactStore(tmp_path / "other").verify(ref)  # units looked up beside `ref`, not in other/
    dest = ArtifactStore(tmp_path / "run")
    copied = copy_verified(ref, dest)
    dest.verify(copied)
    assert {k for _, k, _ in iter_unit_files(dest.root)} == set(ref.manifest["units"])
    unit_path(ref.path.parent.parent, "chunks", sorted(ref.manifest["units"])[0]).unlink()
    with pytest.raises(ArtifactCorrupt, match="missing"):
        copy_verified(ref, ArtifactStore(tmp_path / "run2"))
    assert ArtifactStore(tmp_path / "run2").get("chunks", ref.key) is None


class _DictUnits:
    """An in-memory `Units` memo that counts what it served."""

    def __init__(self) -> None:
        self.data: dict[str, Mapping[str, Any]] = {}
        self.hits = 0

    def get(self, key: str) -> Mapping[str, Any] | None:
        got = self.data.get(key)
        self.hits += got is not None
        return got

    def put(self, key: str, arrays: Mapping[str, Any]) -> None:
        self.data[key] = {k: np.array(v) for k, v in arrays.items()}


def test_features_units_equal_direct_and_survive_extension() -> None:
    from sonarmap.stages.features.calibration import calibration_sample
    from sonarmap.stages.features.stage import FeaturesConfig, features_and_calibration
    from sonarmap.stages.kernels.time_grid import sampled_by_time
    from tests.fixtures.tiny_keyframes import tiny_keyframes

    frames = list(tiny_keyframes())
    cfg = FeaturesConfig()
    n = len(frames) * 9 // 10
    t = np.array([f.t_ns for f in frames], np.int64)
    # The sample of the shorter recording is the longer one's (the grid keeps its period).
    assert sampled_by_time(t[:n], 3).tolist() == sampled_by_time(t, 3).tolist()
    sample = calibration_sample(frames[:n], n=3)
    memo = _DictUnits()
    short, short_doc = features_and_calibration(frames[:n], cfg, memo, sample=sample)
    assert (len(memo.data), memo.hits) == (n + 1, 0)  # a unit per keyframe, the calibration
    plain, plain_doc = features_and_calibration(frames[:n], cfg, sample=sample)
    assert short.equals(plain) and short_doc == plain_doc
    sample = calibration_sample(frames, n=3)
    longer, _ = features_and_calibration(frames, cfg, memo, sample=sample)
    assert memo.hits == n + 1 and len(memo.data) == len(frames) + 1
    assert longer.equals(features_and_calibration(frames, cfg, sample=sample)[0])
    # Another keyframe spacing: every other keyframe, the same calibration pairs (stage
    # `keyframes` samples pings, not keyframes): all units are served, none computed.
    hits, stored = memo.hits, len(memo.data)
    sparse = features_and_calibration(frames[::2], cfg, memo, sample=sample)
    assert memo.hits - hits == len(frames[::2]) + 1 and len(memo.data) == stored
    direct = features_and_calibration(frames[::2], cfg, sample=sample)
    assert sparse[0].equals(direct[0]) and sparse[1] == direct[1]


def test_sweep_line_says_what_each_stage_reused() -> None:
    from sonarmap.pipeline.commands.sweep import units_reused

    stages = [{"stage": "keyframes"}, {"stage": "features", "units": [120, 10]}]
    assert units_reused(stages) == "; units reused: features 120/130"
    assert units_reused([{"stage": "features", "units": None}]) == ""


def test_push_and_pull_carry_the_units_and_pull_refuses_an_altered_one(tmp_path: Path) -> None:
    from sonarmap.pipeline.engine.share.push_pull import pull, push

    data = tmp_path / "rec.bin"
    data.write_bytes(bytes(range(64)))
    cold = _run(data, tmp_path / "alice")
    listed = cold.artifacts["chunks"].manifest["units"]
    remote = tmp_path / "remote"
    push(ArtifactStore(tmp_path / "alice"), str(remote), ["chunks"], create=True)
    assert {p.name for p in (remote / "units" / "chunks").rglob("*") if p.is_file()} == set(listed)
    bob = ArtifactStore(tmp_path / "bob")
    (ref,) = pull(bob, str(remote), ["chunks"])
    bob.verify(ref)
    # in the pulled pool, by content: never among the units a run here may reuse
    assert not list(iter_unit_files(bob.root))
    shas = {entry["sha256"] for entry in listed.values()}
    assert {sha for _, sha, _ in iter_pulled_unit_files(bob.root)} == shas
    victim = unit_path(remote, "chunks", sorted(listed)[0])
    raw = bytearray(victim.read_bytes())
    raw[-1] ^= 1
    victim.write_bytes(bytes(raw))
    with pytest.raises(ArtifactCorrupt):
        pull(ArtifactStore(tmp_path / "carol"), str(remote), ["chunks"])
    assert not list(iter_unit_files(tmp_path / "carol"))


def test_a_remote_s_swapped_units_never_enter_a_run_here(tmp_path: Path) -> None:
    """A remote can vouch for its artifacts' files, not for what a unit of a key must
    hold: units swapped (with their manifest entries) on a remote passed `pull` and
    `--verify`, and a later run here assembled its artifact from them (other bytes under
    the honest key). Pulled units now serve only the artifacts that list them, and a
    unit's digest binds it to its key: the swap is refused at `pull`."""
    import json

    from sonarmap.pipeline.engine.share.push_pull import pull, push

    data = tmp_path / "rec.bin"
    data.write_bytes(bytes(range(64)))
    honest = _bytes(_run(data, tmp_path / "alice"))
    remote = tmp_path / "remote"
    push(ArtifactStore(tmp_path / "alice"), str(remote), ["chunks"], create=True)
    (manifest_path,) = (remote / "chunks").glob("*/manifest.json")
    manifest = json.loads(manifest_path.read_text())
    a, b = sorted(manifest["units"])[:2]
    pa_, pb_ = unit_path(remote, "chunks", a), unit_path(remote, "chunks", b)
    raw_a, raw_b = pa_.read_bytes(), pb_.read_bytes()
    pa_.write_bytes(raw_b)
    pb_.write_bytes(raw_a)
    manifest["units"][a], manifest["units"][b] = manifest["units"][b], manifest["units"][a]
    manifest_path.write_text(json.dumps(manifest))
    bob = ArtifactStore(tmp_path / "bob")
    with pytest.raises(ArtifactCorrupt, match="another unit's file"):
        pull(bob, str(remote), ["chunks"])
    COMPUTED.clear()
    again = _run(data, tmp_path / "bob")
    assert COMPUTED["chunks"] == 4  # every unit computed here, none taken from the remote
    assert _bytes(again) == honest


def test_gc_broken_removes_an_artifact_whose_unit_is_gone(tmp_path: Path) -> None:
    """`--verify` refused it and named `gc --broken`, which found nothing to remove."""
    data = tmp_path / "rec.bin"
    data.write_bytes(bytes(range(64)))
    store = ArtifactStore(tmp_path / "st")
    ref = _run(data, store.root).artifacts["chunks"]
    unit_path(store.root, "chunks", sorted(ref.manifest["units"])[0]).unlink()
    with pytest.raises(ArtifactCorrupt, match="missing"):
        store.verify(ref)
    out = store.gc(broken=True)
    assert out["removed"] == [f"chunks/{ref.key}"] and "missing" in out["broken"][0]
    assert store.get("chunks", ref.key) is None


def test_a_unit_that_is_a_link_is_refused_not_followed(tmp_path: Path) -> None:
    data = tmp_path / "rec.bin"
    data.write_bytes(bytes(range(64)))
    store = ArtifactStore(tmp_path / "st")
    ref = _run(data, store.root).artifacts["chunks"]
    victim = unit_path(store.root, "chunks", sorted(ref.manifest["units"])[0])
    outside = tmp_path / "outside"
    outside.write_bytes(victim.read_bytes())
    victim.unlink()
    victim.symlink_to(outside)  # the same bytes, out of the store
    with pytest.raises(ArtifactCorrupt, match="not a plain file"):
        store.verify(ref)
    victim.unlink()
    victim.symlink_to("/dev/zero")  # read whole, it never ends
    with pytest.raises(ArtifactCorrupt, match="not a plain file"):
        store.verify(ref)
    COMPUTED.clear()
    shutil.rmtree(ref.path)  # as `gc --broken` does
    again = _run(data, store.root)  # a run recomputes it, with a line
    assert COMPUTED["chunks"] == 1 and not victim.is_symlink()
    assert "not a plain file" in again.artifacts["chunks"].manifest["unit_warnings"][0]


def test_a_recording_replaced_after_its_fingerprint_is_refused_and_nothing_kept(
    tmp_path: Path,
) -> None:
    """A recording replaced (or still growing) between fingerprinting and reading: every
    artifact and the dataset's unit were stored under the old content's key, and later
    runs of the real file were served the other recording's map (campaign 11 #2)."""
    from sonarmap.pipeline.engine.errors import SourceError

    data = tmp_path / "rec.bin"
    data.write_bytes(bytes(range(64)))
    store = tmp_path / "st"
    ctx = make_context(
        data, stages=STAGES, overrides=(), store_dir=store,
        parts=lambda p: [p], opener=lambda _section: data.read_bytes(),
    )  # fmt: skip
    planned = plan(ctx.stages, ctx.config, ctx.dataset, ctx.store)
    replacement = tmp_path / "other.bin"
    replacement.write_bytes(bytes(range(100, 164)))
    replacement.replace(data)  # as `mv` does: another inode under the name
    with pytest.raises(SourceError, match="changed while sonarmap read it"):
        execute(planned, ctx.config, ctx.dataset, ctx.store)
    assert ArtifactStore(store).get("chunks", planned[0].key) is None
    assert list(iter_unit_files(store)) == []
