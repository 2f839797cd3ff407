"""Store faults on the way in: `pull` refuses what it cannot check, before committing.

Every case leaves the local store empty (all-or-nothing), is one line through the CLI
(exit 2), and an escaping upstream address is refused before any file is opened.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from fsspec.implementations.local import LocalFileSystem
from test_engine_cache import run_toy
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.errors import ArtifactCorrupt
from sonarmap.pipeline.engine.share.push_pull import pull, push
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore


@pytest.fixture
def remote(tmp_path: Path) -> Path:
    data = tmp_path / "raw.bin"
    data.write_bytes(bytes(range(256)) * 4)
    run_toy(data, tmp_path / "alice")
    remote = tmp_path / "remote"
    push(ArtifactStore(tmp_path / "alice"), str(remote), ["summary"], create=True)
    return remote


def _edit(remote: Path, stage: str, change: Callable[[dict[str, Any], Path], Any]) -> None:
    manifest_path = next(remote.glob(f"{stage}/*/manifest.json"))
    doc = json.loads(manifest_path.read_text())
    doc = change(doc, manifest_path.parent)
    manifest_path.write_text(json.dumps(doc))


def _no_recipe(doc: dict[str, Any], _dir: Path) -> dict[str, Any]:
    del doc["recipe"]
    return doc


def _junk_parquet(doc: dict[str, Any], directory: Path) -> dict[str, Any]:
    junk = b"13 bytes junk"
    (directory / "d.parquet").write_bytes(junk)
    doc["files"]["d.parquet"] = {"sha256": hashlib.sha256(junk).hexdigest(), "size": len(junk)}
    return doc


def _junk_json(doc: dict[str, Any], directory: Path) -> dict[str, Any]:
    junk = b"{not json"
    (directory / "s.json").write_bytes(junk)
    doc["files"]["s.json"] = {"sha256": hashlib.sha256(junk).hexdigest(), "size": len(junk)}
    return doc


def _files_string(doc: dict[str, Any], _dir: Path) -> dict[str, Any]:
    doc["files"] = "d.parquet"
    return doc


CASES = {
    "manifest without recipe": ("double", _no_recipe, "no recipe"),
    "junk parquet with matching sha256": ("double", _junk_parquet, "does not parse as parquet"),
    "junk json with matching sha256": ("summary", _junk_json, "does not parse as json"),
    "manifest is a JSON list": ("double", lambda _d, _p: [], "JSON list"),
    "files is a string": ("double", _files_string, "files"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_pull_refuses_and_leaves_the_store_unchanged(
    remote: Path, tmp_path: Path, case: str
) -> None:
    stage, change, message = CASES[case]
    _edit(remote, stage, change)
    bob = ArtifactStore(tmp_path / "bob")
    with pytest.raises(ArtifactCorrupt, match=message):
        pull(bob, str(remote), ["summary"])
    assert list(bob.scan()) == []
    res = CliRunner().invoke(app, ["pull", str(remote), "summary", "--store", str(bob.root)])
    assert res.exit_code == 2, res.output
    assert res.stderr.count("\n") == 1 and message in res.stderr


def test_escaping_upstream_address_is_refused_before_any_io(
    remote: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A decoy manifest where "../" would lead: it must never be opened.
    decoy = tmp_path / "outside" / ("0" * 64)
    decoy.mkdir(parents=True)
    (decoy / "manifest.json").write_text("{}")

    def escape(doc: dict[str, Any], _dir: Path) -> dict[str, Any]:
        doc["input_artifacts"] = {"double.table": "../outside/" + "0" * 64}
        return doc

    _edit(remote, "summary", escape)
    opened: list[str] = []
    for method in ("cat_file", "get_file", "open", "exists", "ls"):
        original = getattr(LocalFileSystem, method)

        def spy(self: Any, path: Any, *a: Any, _orig: Any = original, **k: Any) -> Any:
            opened.append(str(path))
            return _orig(self, path, *a, **k)

        monkeypatch.setattr(LocalFileSystem, method, spy)
    with pytest.raises(ArtifactCorrupt, match="input_artifacts"):
        pull(ArtifactStore(tmp_path / "bob"), str(remote), ["summary"])
    assert opened and not any("outside" in p or ".." in p for p in opened), opened
