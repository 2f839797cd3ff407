"""Store faults: a tampered or broken store is reported in one line (exit 2), healed by
`gc`, and never turns into a recomputed artifact committed under a clean key.

The toy graph stands in for the real one: `source/t.parquet` plays `keyframes.parquet`
(the first stage's table), `double/d.parquet` plays `fuse/fused.parquet` (a table two
stages read). The checks are in the engine, not in any stage.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import Result
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore

runner = CliRunner()


@pytest.fixture
def toy(toy_cli: Path, tmp_path: Path) -> tuple[Path, Path]:
    """(dataset, store) with the CLI pointed at the toy graph and the store computed once."""
    data = toy_cli
    store = tmp_path / "store"
    assert cli("run", data, "--store", store).exit_code == 0
    return data, store


def cli(*args: object) -> Result:
    return runner.invoke(app, [str(a) for a in args])


def run_json(data: Path, store: Path, *extra: object) -> dict[str, str]:
    res = cli("run", data, "--store", store, "--json", "-q", *extra)
    assert res.exit_code == 0, res.output
    return {s["stage"]: s["status"] for s in json.loads(res.stdout)["stages"]}


def assert_one_line_error(res: Result, *needles: str) -> None:
    assert res.exit_code == 2, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def artifact(store: Path, stage: str) -> Path:
    (path,) = (store / stage).iterdir()
    return path


def flip(path: Path, at: int) -> None:
    raw = bytearray(path.read_bytes())
    raw[at % len(raw)] ^= 0xFF
    path.write_bytes(bytes(raw))


def digests(store: Path) -> dict[str, str]:
    return {
        f"{f.parent.parent.name}/{f.name}": hashlib.sha256(f.read_bytes()).hexdigest()
        for f in sorted(store.glob("*/*/*"))
        if f.parent.parent.name not in ("runs",) and f.name != "manifest.json"
    }


# -- item 1: tampered artifacts are never used -------------------------------------------
TAMPER = [
    (stage, name, reader, at)
    for stage, name, reader in [
        ("source", "t.parquet", "double"),
        ("source", "t.parquet", "count"),
        ("double", "d.parquet", "summary"),
    ]
    for at in (0, 300, -1)
]


@pytest.mark.parametrize(("stage", "name", "reader", "at"), TAMPER)
def test_flipped_byte_is_refused_then_gc_broken_heals(
    toy: tuple[Path, Path], stage: str, name: str, reader: str, at: int
) -> None:
    data, store = toy
    clean = digests(store)
    victim = artifact(store, stage)
    reader_key = artifact(store, reader).name
    flip(victim / name, at)
    # Forcing the reader must not recompute it from the corrupt input.
    res = cli("run", data, "--store", store, "--force", reader, "-q")
    assert_one_line_error(res, f"{stage}/{victim.name[:12]}", name, "gc --broken", "--force")
    assert ArtifactStore(store).get(reader, reader_key) is None
    assert_one_line_error(cli("show", stage, "--store", store, "--verify"), name)
    healed = cli("gc", "--store", store, "--broken", "--json")
    assert healed.exit_code == 0, healed.output
    assert f"{stage}/{victim.name}" in json.loads(healed.stdout)["removed"]
    statuses = run_json(data, store)
    assert statuses[stage] == "computed" and statuses[reader] == "computed"
    assert digests(store) == clean


def test_changed_config_downstream_of_a_tampered_table_is_refused(toy: tuple[Path, Path]) -> None:
    data, store = toy
    flip(artifact(store, "double") / "d.parquet", 100)
    res = cli("run", data, "--store", store, "--set", "summary.label=other", "-q")
    assert_one_line_error(res, "double/", "d.parquet", "sha256")
    assert len(list((store / "summary").iterdir())) == 1


def test_junk_with_a_consistent_manifest_is_one_line_not_a_traceback(
    toy: tuple[Path, Path],
) -> None:
    data, store = toy
    victim = artifact(store, "double")
    junk = b"not parquet!!"
    (victim / "d.parquet").write_bytes(junk)
    manifest = json.loads((victim / "manifest.json").read_text())
    manifest["files"]["d.parquet"] = {"sha256": hashlib.sha256(junk).hexdigest(), "size": 13}
    (victim / "manifest.json").write_text(json.dumps(manifest))
    res = cli("run", data, "--store", store, "--force", "summary", "-q")
    assert_one_line_error(res, "d.parquet", "does not parse as parquet")


def test_file_missing_from_the_manifest_is_never_read(toy: tuple[Path, Path]) -> None:
    data, store = toy
    victim = artifact(store, "double")
    manifest = json.loads((victim / "manifest.json").read_text())
    del manifest["files"]["d.parquet"]
    (victim / "manifest.json").write_text(json.dumps(manifest))
    res = cli("run", data, "--store", store, "--force", "summary", "-q")
    assert_one_line_error(res, "lists no 'd.parquet'")


# -- item 2: a broken store heals itself, or says how -------------------------------------
def test_manifestless_directory_is_replaced_and_collected(toy: tuple[Path, Path]) -> None:
    data, store = toy
    victim = artifact(store, "double")
    (victim / "manifest.json").unlink()
    listed = json.loads(cli("ls", "--store", store, "--json").stdout)
    assert "double" not in {a["stage"] for a in listed["artifacts"]}
    assert listed["broken"] == [f"double/{victim.name[:12]}: no manifest"]
    assert run_json(data, store)["double"] == "computed"
    ArtifactStore(store).verify(ArtifactStore(store).find("double"))
    (artifact(store, "double") / "manifest.json").unlink()
    # Names the store never writes are not its own: gc leaves them alone.
    foreign = [store / "double" / "notes", store / "my-notes" / ("ab" * 32)]
    for path in foreign:
        path.mkdir(parents=True)
    report = json.loads(cli("gc", "--store", store, "--json").stdout)
    assert report["removed"] == [f"double/{victim.name}"] and not victim.exists()
    assert all(path.is_dir() for path in foreign)


BAD_MANIFESTS = {
    "json list": b"[]",
    "files is a string": None,
    "not json": b'{"stage": ',
    "empty": b"",
    "not utf-8": b"\xff\xfe{}",
    "names another artifact": None,
    "negative size": None,
    "escaping upstream address": None,
}


def _bad_manifest(case: str, original: dict) -> bytes:
    raw = BAD_MANIFESTS[case]
    if raw is not None:
        return raw
    doc = json.loads(json.dumps(original))
    if case == "files is a string":
        doc["files"] = "d.parquet"
    elif case == "names another artifact":
        doc["stage"] = "summary"
    elif case == "negative size":
        doc["files"]["d.parquet"]["size"] = -1
    else:
        doc["input_artifacts"] = {"source.table": "../../etc/" + "0" * 64}
    return json.dumps(doc).encode()


@pytest.mark.parametrize("case", sorted(BAD_MANIFESTS))
def test_bad_manifest_is_one_line_everywhere_and_gc_removes_it(
    toy: tuple[Path, Path], case: str
) -> None:
    data, store = toy
    victim = artifact(store, "double")
    original = json.loads((victim / "manifest.json").read_text())
    (victim / "manifest.json").write_bytes(_bad_manifest(case, original))
    assert_one_line_error(cli("run", data, "--store", store, "-q"), "manifest", "gc --broken")
    listed = cli("ls", "--store", store, "--json")
    assert listed.exit_code == 0, listed.output
    assert len(json.loads(listed.stdout)["artifacts"]) == 3
    assert len(json.loads(listed.stdout)["broken"]) == 1
    assert cli("show", "summary", "--store", store).exit_code == 0
    assert_one_line_error(cli("show", "double", "--store", store), "manifest")
    assert_one_line_error(cli("show", victim.name[:10], "--store", store), "manifest")
    report = cli("gc", "--store", store, "--json")
    assert report.exit_code == 0, report.output
    assert json.loads(report.stdout)["removed"] == [f"double/{victim.name}"]
    assert run_json(data, store)["double"] == "computed"


def _dead_pid() -> int:
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], check=True,
                          capture_output=True, text=True)  # fmt: skip
    return int(proc.stdout)


def test_gc_removes_leftovers_of_dead_processes_only(toy: tuple[Path, Path]) -> None:
    _, store = toy
    dead, live = _dead_pid(), subprocess.Popen([sys.executable, "-c", "input()"],
                                               stdin=subprocess.PIPE)  # fmt: skip
    try:
        paths = {}
        for who, pid in (("dead", dead), ("live", live.pid)):
            paths[who] = [
                store / "runs" / f".0123abcd.{pid}.tmp",
                store / ".cache" / f"fingerprints.tmp{pid}",
                store / ".tmp" / f"double-0123456789abcdef-{pid}-deadbeef",
                store / ".tmp" / f"pull-{pid}-0badcafe",
            ]
            for p in paths[who]:
                p.parent.mkdir(parents=True, exist_ok=True)
                if p.parent.name == ".tmp":
                    p.mkdir()
                    (p / "part.bin").write_bytes(b"x" * 10)
                else:
                    p.write_text("{}")
        dry = json.loads(cli("gc", "--store", store, "--dry-run", "--json").stdout)
        assert dry["tmp_removed"] == 4 and all(p.exists() for p in paths["dead"])
        report = json.loads(cli("gc", "--store", store, "--json").stdout)
        assert report["tmp_removed"] == 4 and report["removed"] == []
        assert not any(p.exists() for p in paths["dead"])
        assert all(p.exists() for p in paths["live"])
    finally:
        live.kill()
        live.wait()
    assert json.loads(cli("gc", "--store", store, "--json").stdout)["tmp_removed"] == 4
