"""What a user's slip must not destroy: an output path that is a device, a FIFO, a folder,
a link or the input itself; `gc` on a folder that is not a store or with a run record it
cannot read; an artifact directory that is a link out of the store."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from test_engine_cache import did, run_toy
from test_robust_clocks import _nav, _pings, _write
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.errors import ArtifactCorrupt, StoreError
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
from sonarmap.pipeline.formats.atomic import atomic_output, check_output_path


def _recording(tmp_path: Path) -> Path:
    return _write(tmp_path / "rec.mcap", _pings(6) + _nav([k * 0.1 for k in range(60)]))


def test_an_output_that_is_not_a_regular_file_is_refused(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    folder = tmp_path / "folder"
    folder.mkdir()
    precious = tmp_path / "precious.txt"
    precious.write_text("keep me")
    link = tmp_path / "link.mcap"
    link.symlink_to(precious)
    for path, kind in ((fifo, "a FIFO"), (folder, "a directory"), (link, "a symbolic link")):
        with pytest.raises(OSError, match=f"exists and is {kind}; refusing") as err:
            check_output_path(path)
        assert err.value.filename == str(path)
        with pytest.raises(OSError), atomic_output(path) as f:
            f.write(b"x")
    assert fifo.exists() and folder.is_dir() and link.is_symlink()
    assert precious.read_text() == "keep me"
    check_output_path(tmp_path / "new.mcap")  # missing: fine
    check_output_path(precious)  # an earlier regular file is replaced
    with pytest.raises(OSError, match="is the input"):
        check_output_path(tmp_path / "." / "precious.txt", [precious])


def test_convert_refuses_to_write_onto_its_input_a_fifo_or_an_unknown_option(
    tmp_path: Path,
) -> None:
    rec = _recording(tmp_path)
    before = rec.read_bytes()
    res = CliRunner().invoke(app, ["convert", str(rec), "-o", str(rec)])
    assert res.exit_code == 2, res.output
    assert "is the input" in res.stderr and rec.read_bytes() == before
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    res = CliRunner().invoke(app, ["convert", str(rec), "-o", str(fifo)])
    assert res.exit_code == 2 and "a FIFO" in res.stderr and fifo.exists()
    for item, words in (
        ("keyframes.nope=1", "not a reader option"),
        ("fuse.patch_size_px=7", "not a reader option"),
        ("keyframes.horizontal_topc=/x", "did you mean keyframes.horizontal_topic"),
        ("keyframes.dvl_max_velocity_mps=-1", "keyframes.dvl_max_velocity_mps"),
    ):
        res = CliRunner().invoke(
            app, ["convert", str(rec), "-o", str(tmp_path / "c.mcap"), "-s", item]
        )
        assert res.exit_code == 2, (item, res.output)
        assert words in res.stderr, (item, res.stderr)
        assert not (tmp_path / "c.mcap").exists()


def test_simulate_refuses_a_fifo_before_simulating(tmp_path: Path) -> None:
    fifo = tmp_path / "sim.fifo"
    os.mkfifo(fifo)
    res = CliRunner().invoke(app, ["simulate", "-o", str(fifo), "--goals", "1", "-q"])
    assert res.exit_code == 2, res.output
    assert "a FIFO" in res.stderr and "frames" not in res.stderr


def _toy_store(tmp_path: Path) -> Path:
    data = tmp_path / "raw.bin"
    data.write_bytes(bytes(range(256)) * 4)
    store = tmp_path / "store"
    assert did(run_toy(data, store))
    return store


@pytest.mark.parametrize("content", [b"", b"\x00\xff{{", b"[]"], ids=["empty", "junk", "list"])
def test_gc_removes_nothing_while_a_run_record_cannot_be_read(
    tmp_path: Path, content: bytes
) -> None:
    store_dir = _toy_store(tmp_path)
    store = ArtifactStore(store_dir)
    artifacts = sorted(r.path for r in store.iter_artifacts())
    (record,) = (store_dir / "runs").glob("*.json")
    record.write_bytes(content)
    for dry_run in (True, False):
        with pytest.raises(StoreError, match=f"{record.name}: unreadable run record"):
            store.gc(dry_run=dry_run)
    assert sorted(r.path for r in store.iter_artifacts()) == artifacts
    res = CliRunner().invoke(app, ["gc", "--store", str(store_dir)])
    assert res.exit_code == 2 and "unreadable run record" in res.stderr
    assert store.run_records() == []  # the readers that only list skip it, as before


def test_gc_refuses_a_folder_that_is_not_a_store(tmp_path: Path) -> None:
    project = tmp_path / "proj"
    for sub in ("evaluate/2024", "train/001", "features/cafe"):
        (project / sub).mkdir(parents=True)
        (project / sub / "results.csv").write_text("mine")
    res = CliRunner().invoke(app, ["gc", "--store", str(project)])
    assert res.exit_code == 2, res.output
    assert "not a sonarmap store" in res.stderr
    assert all((project / sub / "results.csv").is_file() for sub in ("evaluate/2024", "train/001"))
    assert not (project / ".locks").exists()


def test_an_artifact_directory_linked_out_of_the_store_is_refused_and_replaced(
    tmp_path: Path,
) -> None:
    store_dir = _toy_store(tmp_path)
    store = ArtifactStore(store_dir)
    ref = next(r for r in store.iter_artifacts() if r.stage == "source")
    outside = tmp_path / "outside"
    ref.path.rename(outside)
    ref.path.symlink_to(outside, target_is_directory=True)
    with pytest.raises(ArtifactCorrupt, match="a symbolic link, not an artifact directory"):
        store.get(ref.stage, ref.key)
    data = tmp_path / "raw.bin"
    result = run_toy(data, store_dir, force=("source",))
    assert "source" in did(result)
    assert ref.path.is_dir() and not ref.path.is_symlink()
    assert (outside / "manifest.json").is_file()  # the link's target is not the store's


def test_ls_of_a_missing_store_says_so(tmp_path: Path) -> None:
    res = CliRunner().invoke(app, ["ls", "--store", str(tmp_path / "typo")])
    assert res.exit_code == 0, res.output
    assert "typo: no store there yet" in res.stderr
