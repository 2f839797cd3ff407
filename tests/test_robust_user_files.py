"""One guarded way to read a user's file (issue 52, root 1): a FIFO, a device behind a
symlink, a folder or a file over its cap is refused in one line naming it, exit 2, within
seconds and 1 GB, whichever command reads it; and a size the user sets is capped by what
it costs (`label export --pixel-m`)."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_labels import _frames
from test_robust_labels import _exported

from sonarmap.pipeline.engine.errors import ConfigError, SourceError
from sonarmap.pipeline.engine.user_files import read_user_file, read_user_json
from sonarmap.pipeline.labels.files import GEOMETRY_FILE, export_labels
from sonarmap.schemas.classes import CLASS_IDS

GIB = 1 << 30


def _limited() -> None:  # the child may not take more than 1 GB of address space (+ python)
    resource.setrlimit(resource.RLIMIT_AS, (2 * GIB, 2 * GIB))


def _cli(*args: str, timeout: float = 30.0) -> subprocess.CompletedProcess[str]:
    """The CLI in a child with a memory limit and a wall-clock limit (a hang fails)."""
    return subprocess.run(
        [sys.executable, "-m", "sonarmap.pipeline", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        preexec_fn=_limited,
        env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )


def _refused(res: subprocess.CompletedProcess[str], path: Path, what: str) -> None:
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert res.returncode == 2 and len(errors) == 1, res.stderr[-2000:]
    assert str(path) in errors[0] and what in errors[0], errors[0]
    assert "Traceback" not in res.stderr


def _swap(path: Path, kind: str) -> None:
    path.unlink()
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "dev-zero":
        path.symlink_to("/dev/zero")
    else:
        path.mkdir()


@pytest.mark.parametrize("kind", ["fifo", "dev-zero", "folder"])
@pytest.mark.parametrize("which", ["coco", "geometry"])
def test_label_import_of_a_file_that_is_not_a_regular_file(
    tmp_path: Path, kind: str, which: str
) -> None:
    coco, geometry = _exported(tmp_path)
    target = coco if which == "coco" else geometry
    _swap(target, kind)
    res = _cli("label", "import", str(coco), "-o", str(tmp_path / "a.yaml"))
    _refused(res, target, "is not a regular file")


def test_a_coco_file_over_the_cap_is_refused_before_it_is_parsed(tmp_path: Path) -> None:
    coco, _ = _exported(tmp_path)
    with coco.open("ab") as f:
        f.write(b" " * (9 << 20))
    res = _cli("label", "import", str(coco), "-o", str(tmp_path / "a.yaml"), timeout=10)
    _refused(res, coco, "over the limit of 8388608")


@pytest.mark.parametrize("kind", ["fifo", "dev-zero"])
def test_a_beam_table_that_is_not_a_regular_file(tmp_path: Path, kind: str) -> None:
    from sonarmap.pipeline.readers.sonar_models import load_sonar

    table = tmp_path / "beams.csv"
    table.write_text("-10\n0\n10\n")
    _swap(table, kind)
    with pytest.raises(
        ConfigError, match=r"beams\.csv.*(not a regular file|nor a beam-table file)"
    ):
        load_sonar(str(table))


def test_a_usage_error_is_still_a_usage_error() -> None:
    res = _cli("config", "check", "--no-such-option")
    assert res.returncode == 2 and "No such option" in res.stderr and "internal" not in res.stderr


def test_the_guarded_reader_itself(tmp_path: Path) -> None:
    f = tmp_path / "x.json"
    f.write_text('{"a": 1}')
    assert read_user_json(f, "thing", SourceError, 100) == {"a": 1}
    with pytest.raises(SourceError, match=r"x\.json: thing is 8 bytes, over the limit of 7"):
        read_user_file(f, "thing", SourceError, 7)
    f.write_bytes(b'{"a": NaN}')
    with pytest.raises(SourceError, match="NaN is not a JSON number"):
        read_user_json(f, "thing", SourceError, 100)
    f.write_bytes(b"[" * 100_000)
    with pytest.raises(SourceError, match="not a thing"):
        read_user_json(f, "thing", SourceError, 1 << 20)
    f.write_bytes(b"\xff\xfe{}")
    with pytest.raises(SourceError, match="not a thing"):
        read_user_json(f, "thing", SourceError, 100)
    with pytest.raises(SourceError, match="cannot read thing"):
        read_user_file(tmp_path / "missing", "thing", SourceError, 100)


def test_a_pixel_side_is_capped_by_the_image_it_makes(tmp_path: Path) -> None:
    frames = _frames([1_000_000_000])
    with pytest.raises(
        ConfigError,
        match=r"--pixel-m 0.001: a pixel of 0.001 m makes a \d+ x "
        r"\d+ image .*at most 4194304 pixels\): use 0.0\d+ m or more",
    ):
        export_labels(tmp_path / "d.mcap", tmp_path / "x", frames, {}, {}, CLASS_IDS, 1.0, 0.001)
    assert not (tmp_path / "x" / "images").exists()
    done = export_labels(tmp_path / "d.mcap", tmp_path / "y", frames, {}, {}, CLASS_IDS, 1.0, 0.02)
    assert done.images == 1 and (tmp_path / "y" / GEOMETRY_FILE).is_file()
    assert np.isfinite(0.02)
