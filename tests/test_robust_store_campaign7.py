"""Campaign 7: the store and sharing as a user meets them (each test failed before its fix).

The work units a remote hands over are covered in test_work_units.py (swapped units,
`gc --broken` and units, a unit that is a link).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from test_engine_cache import run_toy
from test_share_trust import _cli, _one_error_line

from sonarmap.pipeline.engine.errors import ArtifactCorrupt, StoreError
from sonarmap.pipeline.engine.hashing import FingerprintCache, sha256_file
from sonarmap.pipeline.engine.share.push_pull import pull, push
from sonarmap.pipeline.engine.share.transfer import download
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
from sonarmap.pipeline.engine.store.integrity import verify_file
from sonarmap.pipeline.engine.store.units import unit_entries


def _store(tmp_path: Path, name: str = "alice") -> ArtifactStore:
    data = tmp_path / "raw.bin"
    data.write_bytes(bytes(range(256)) * 16)
    run_toy(data, tmp_path / name)
    return ArtifactStore(tmp_path / name)


def _addresses(store: ArtifactStore) -> set[str]:
    return {f"{r.stage}/{r.key}" for r in store.iter_artifacts()}


def test_a_negative_unit_size_is_refused_before_any_download(tmp_path: Path) -> None:
    """`"size": -2` made the download read the whole remote file in one call (1.6 GB)."""
    listed = {"units": {"a" * 64: {"sha256": "b" * 64, "size": -2}}}
    with pytest.raises(ArtifactCorrupt, match="malformed unit"):
        unit_entries(listed, "remote chunks/aaaa")
    with pytest.raises(ArtifactCorrupt, match="declares -2 bytes"):
        download(object(), "src", tmp_path / "dst", -2, "b" * 64, "remote units/x")


@pytest.mark.parametrize("text", ["[]", '{"/data/rec.mcap": 5}', '{"x": {"stat": 1}}'])
def test_a_fingerprint_cache_of_another_shape_costs_a_hash_not_the_store(
    tmp_path: Path, text: str
) -> None:
    """Valid JSON of another shape made every run and status exit 1 (AttributeError)."""
    cache_file = tmp_path / ".cache" / "fingerprints.json"
    cache_file.parent.mkdir()
    cache_file.write_text(text)
    data = tmp_path / "rec.bin"
    data.write_bytes(b"sonar" * 100)
    assert FingerprintCache(cache_file).file_digest(data) == sha256_file(data)


def test_gc_leaves_folders_the_store_never_wrote(tmp_path: Path) -> None:
    """Plain `gc` removed a user's `exports/2024/` (an identifier, then hex digits), and
    through a stage folder that was a link, a folder outside the store."""
    store = _store(tmp_path)
    exports = store.root / "exports" / "2024"
    exports.mkdir(parents=True)
    (exports / "map.ply").write_text("ply")
    outside = tmp_path / "outside" / "double"
    shutil.copytree(store.root / "double", outside)
    (outside / "abc123").mkdir()
    (outside / "abc123" / "notes.txt").write_text("precious")
    shutil.rmtree(store.root / "double")
    (store.root / "double").symlink_to(outside)
    before = sorted(p.relative_to(tmp_path) for p in outside.rglob("*"))
    store.gc()
    assert (exports / "map.ply").read_text() == "ply"
    assert sorted(p.relative_to(tmp_path) for p in outside.rglob("*")) == before


def test_gc_keeps_what_a_pull_fetched(tmp_path: Path) -> None:
    """A pull wrote no run record, so the next `gc` removed everything it fetched."""
    alice = _store(tmp_path)
    remote = tmp_path / "remote"
    push(alice, str(remote), create=True)
    bob = ArtifactStore(tmp_path / "bob")
    pull(bob, str(remote), ["summary"])
    fetched = _addresses(bob)
    assert len(fetched) >= 3  # summary and its upstream
    out = bob.gc()
    assert out["removed"] == [] and _addresses(bob) == fetched


def test_gc_refuses_a_runs_entry_that_is_not_a_folder(tmp_path: Path) -> None:
    """With `runs` a file, gc read no record and removed every artifact."""
    store = _store(tmp_path)
    held = _addresses(store)
    shutil.move(store.root / "runs", tmp_path / "runs.bak")
    (store.root / "runs").write_text("")
    with pytest.raises(StoreError, match="unreadable run records"):
        store.gc()
    assert _addresses(store) == held


def test_pull_replaces_a_damaged_local_copy(tmp_path: Path) -> None:
    """It said "pulled 0 artifacts" and left the truncated file in place."""
    alice = _store(tmp_path)
    remote = tmp_path / "remote"
    push(alice, str(remote), create=True)
    bob = ArtifactStore(tmp_path / "bob")
    pull(bob, str(remote), ["double"])
    (ref,) = [r for r in bob.iter_artifacts() if r.stage == "double"]
    damaged = ref.path / "d.parquet"
    damaged.write_bytes(damaged.read_bytes()[:100])
    # a pull that fails changes nothing locally: the damaged copy waits for a good one
    broken = tmp_path / "broken"
    shutil.copytree(remote, broken)
    (broken / "double" / ref.key / "d.parquet").unlink()
    with pytest.raises(ArtifactCorrupt, match="missing"):
        pull(bob, str(broken), ["double"])
    assert bob.get("double", ref.key) is not None and len(damaged.read_bytes()) == 100
    refs = pull(bob, str(remote), ["double"])
    assert [f"{r.stage}/{r.key}" for r in refs] == [f"double/{ref.key}"]
    bob.verify(bob.get("double", ref.key))


def test_push_from_a_store_that_is_not_there_is_refused(tmp_path: Path) -> None:
    """A mistyped --store pushed "0 artifacts" with exit 0."""
    remote = tmp_path / "remote"
    remote.mkdir()
    res = _cli("push", str(remote), "--store", str(tmp_path / "stroe"))
    _one_error_line(res, "stroe", "no store there")


def test_a_store_or_a_remote_that_is_a_file_is_named_as_such(tmp_path: Path) -> None:
    """`ls` said "no store there yet"; pull named a made-up path or a manifest."""
    afile = tmp_path / "afile"
    afile.write_text("x")
    _one_error_line(_cli("ls", "--store", str(afile)), "a file, not a store folder")
    res = _cli("pull", str(afile), "--store", str(tmp_path / "bob"))
    _one_error_line(res, "is a file, not a folder of artifacts")


def test_an_artifact_file_linked_out_of_the_store_is_named_with_its_artifact(
    tmp_path: Path,
) -> None:
    store = _store(tmp_path)
    (ref,) = [r for r in store.iter_artifacts() if r.stage == "double"]
    target = tmp_path / "elsewhere.parquet"
    shutil.copy(ref.path / "d.parquet", target)
    (ref.path / "d.parquet").unlink()
    (ref.path / "d.parquet").symlink_to(target)
    with pytest.raises(ArtifactCorrupt) as err:
        verify_file(ref, "d.parquet")
    assert f"artifact double/{ref.key[:12]}: 'd.parquet'" in str(err.value)
    assert "--force double" in str(err.value)
    assert json.loads((ref.path / "manifest.json").read_text())["key"] == ref.key
