"""push/pull through an fsspec remote: verified, all-or-nothing, reused by `run`."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import toy_stages
from test_engine_cache import did, run_toy

from sonarmap.pipeline.engine.errors import ArtifactCorrupt
from sonarmap.pipeline.engine.share.push_pull import pull, push
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore


@pytest.fixture
def pushed(tmp_path: Path) -> tuple[Path, Path]:
    data = tmp_path / "raw.bin"
    data.write_bytes(bytes(range(256)) * 4)
    run_toy(data, tmp_path / "alice")
    remote = tmp_path / "remote"
    addresses = push(ArtifactStore(tmp_path / "alice"), str(remote), ["summary"], create=True)
    assert [a.split("/")[0] for a in addresses] == ["source", "double", "summary"]
    return data, remote


def test_second_store_pulling_computes_nothing(pushed: tuple[Path, Path], tmp_path: Path) -> None:
    data, remote = pushed
    bob = tmp_path / "bob"
    refs = pull(ArtifactStore(bob), str(remote), ["summary"])
    assert {r.stage for r in refs} == {"source", "double", "summary"}
    toy_stages.CALLS.clear()
    result = run_toy(data, bob, until="summary")
    assert did(result) == set()
    assert sum(toy_stages.CALLS.values()) == 0


def test_tampered_file_is_refused_and_store_unchanged(
    pushed: tuple[Path, Path], tmp_path: Path
) -> None:
    _, remote = pushed
    blob = next(remote.glob("double/*/d.bin"))
    raw = blob.read_bytes()
    blob.write_bytes(bytes([raw[0] ^ 1]) + raw[1:])
    bob = ArtifactStore(tmp_path / "bob")
    with pytest.raises(ArtifactCorrupt, match="sha256"):
        pull(bob, str(remote), ["summary"])
    assert list(bob.iter_artifacts()) == []


def test_truncated_transfer_is_refused(pushed: tuple[Path, Path], tmp_path: Path) -> None:
    _, remote = pushed
    table = next(remote.glob("source/*/t.parquet"))
    table.write_bytes(table.read_bytes()[:-10])
    bob = ArtifactStore(tmp_path / "bob")
    with pytest.raises(ArtifactCorrupt, match="size"):
        pull(bob, str(remote), ["summary"])
    assert list(bob.iter_artifacts()) == []


def test_escaping_path_and_forged_key_are_refused(
    pushed: tuple[Path, Path], tmp_path: Path
) -> None:
    _, remote = pushed
    manifest_path = next(remote.glob("summary/*/manifest.json"))
    original = manifest_path.read_text()
    manifest = json.loads(original)
    manifest["files"]["../../../../evil.txt"] = {"sha256": "0" * 64, "size": 1}
    manifest_path.write_text(json.dumps(manifest))
    bob = ArtifactStore(tmp_path / "bob")
    with pytest.raises(ArtifactCorrupt, match="a path outside the artifact"):
        pull(bob, str(remote), ["summary"])
    assert not (tmp_path / "evil.txt").exists()
    forged = json.loads(original)
    forged["config"] = {"label": "forged"}
    forged["recipe"]["config"] = {"label": "forged"}
    manifest_path.write_text(json.dumps(forged))
    with pytest.raises(ArtifactCorrupt, match="recipe"):
        pull(bob, str(remote), ["summary"])
    assert list(bob.iter_artifacts()) == []


def test_cli_push_pull_json(pushed: tuple[Path, Path], tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from sonarmap.pipeline.cli import app

    _, remote = pushed
    runner = CliRunner()
    res = runner.invoke(app, ["pull", str(remote), "--store", str(tmp_path / "carol"), "--json"])
    assert res.exit_code == 0, res.output
    assert len(json.loads(res.stdout)["pulled"]) == 3
    shutil.rmtree(remote / "double")
    res = runner.invoke(app, ["pull", str(remote), "summary", "--store", str(tmp_path / "dave")])
    assert res.exit_code == 2 and "double" in res.stderr
