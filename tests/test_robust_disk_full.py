"""Full disks everywhere (issue 52, root 6): a command that writes and meets a full disk
(ENOSPC while writing or syncing) exits 2 with one line naming the file it was writing,
and leaves neither that file nor a temporary file behind."""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import Any

import pytest
from test_labels import _frames
from test_readers_mcap import write_synthetic
from test_robust_labels import _exported
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.commands._errors import writes_under
from sonarmap.pipeline.formats import atomic
from sonarmap.pipeline.labels.files import export_labels
from sonarmap.schemas.classes import CLASS_IDS


class _FullFile:
    """A file on a disk that fills after `room` bytes."""

    def __init__(self, f: Any, room: int) -> None:
        self._f, self._room = f, room

    def write(self, data: Any) -> int:
        n = len(memoryview(data))
        if n > self._room:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._room -= n
        return int(self._f.write(data))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._f, name)

    def __enter__(self) -> _FullFile:
        return self

    def __exit__(self, *exc: Any) -> None:
        self._f.close()


class _OsOnAFullDisk:
    """`os` as `formats.atomic` sees it, on a full disk (at write or at fsync)."""

    def __init__(self, where: str) -> None:
        self._where = where

    def fdopen(self, fd: int, mode: str) -> Any:
        f = os.fdopen(fd, mode)
        return _FullFile(f, 100) if self._where == "write" else f

    def fsync(self, fd: int) -> None:
        if self._where == "fsync":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        os.fsync(fd)

    def __getattr__(self, name: str) -> Any:
        return getattr(os, name)


@pytest.fixture(params=["write", "fsync"])
def full_disk(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    monkeypatch.setattr(atomic, "os", _OsOnAFullDisk(request.param))
    return str(request.param)


def _one_error(args: list[str], path: Path) -> None:
    res = CliRunner().invoke(app, args)
    errors = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert res.exit_code == 2 and len(errors) == 1, res.output[-2000:]
    assert errors[0] == f"error: {path}: No space left on device", errors[0]
    assert "Traceback" not in res.output


def _nothing_left(folder: Path, *names: str) -> None:
    left = [p.name for p in folder.iterdir()]
    assert not [n for n in left if n.endswith(".tmp") or n in names], left


def test_convert_onto_a_full_disk(tmp_path: Path, full_disk: str) -> None:
    src = tmp_path / "in.mcap"
    with pytest.MonkeyPatch.context() as m:
        m.setattr(atomic, "os", os)
        write_synthetic(src, n_pings=4, labels=False)
    out = tmp_path / "out" / "o.mcap"
    out.parent.mkdir()
    _one_error(["convert", str(src), "-o", str(out)], out)
    _nothing_left(out.parent, "o.mcap")


def test_label_import_onto_a_full_disk(tmp_path: Path, full_disk: str) -> None:
    with pytest.MonkeyPatch.context() as m:
        m.setattr(atomic, "os", os)
        coco, _ = _exported(tmp_path)
    out = tmp_path / "o.annotations.yaml"
    _one_error(["label", "import", str(coco), "-o", str(out)], out)
    _nothing_left(tmp_path, out.name)


def test_label_export_onto_a_full_disk_names_the_file_not_the_store(
    tmp_path: Path, full_disk: str
) -> None:
    store = tmp_path / "store"
    with pytest.raises(OSError) as err, writes_under(store):
        export_labels(tmp_path / "d.mcap", tmp_path / "x", _frames([1_000]), {}, {}, CLASS_IDS, 1.0)
    assert err.value.errno == errno.ENOSPC and "store" not in str(err.value.filename)
    assert Path(err.value.filename).parent == tmp_path / "x" / "images"
    _nothing_left(tmp_path / "x" / "images")


def test_simulate_onto_a_full_disk(tmp_path: Path, full_disk: str) -> None:
    out = tmp_path / "sim.mcap"
    _one_error(["simulate", "--goals", "1", "--duration-s", "1", "-o", str(out), "-q"], out)
    _nothing_left(tmp_path, out.name)
