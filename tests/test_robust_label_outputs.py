"""Outputs the user did not name are never written (issue 52, root 2): `label import`
writes beside the recording only when it exists and is the one the labels came from,
else it asks for -o; an annotation file its own reader would refuse is not written."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest
from test_robust_labels import _edit, _exported, _import

from sonarmap.pipeline.labels.files import GEOMETRY_FILE


def _no_yaml_written(*folders: Path) -> None:
    for folder in folders:
        assert not [p for p in folder.rglob("*") if p.name.endswith(".annotations.yaml")]


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.update(recording=""), "names no recording"),
        (lambda d: d.update(recording="/nowhere/at/all/dive.mcap"), "does not exist"),
        (lambda d: d.pop("recording_identity"), "records no identity"),
    ],
)
def test_no_recording_to_write_beside_asks_for_o(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, change: Any, message: str
) -> None:
    coco, geometry = _exported(tmp_path)
    _edit(geometry, change)
    monkeypatch.chdir(tmp_path)  # `"recording": ""` once wrote ./.annotations.yaml here
    code, errors = _import(coco)
    assert code == 2 and len(errors) == 1 and message in errors[0] and "-o" in errors[0]
    _no_yaml_written(tmp_path)
    assert not (tmp_path / ".annotations.yaml").exists()
    code, errors = _import(coco, "-o", str(tmp_path / "named.annotations.yaml"))
    assert code == 0 and (tmp_path / "named.annotations.yaml").is_file()


def test_a_replaced_recording_is_not_written_beside(tmp_path: Path) -> None:
    coco, _ = _exported(tmp_path)
    (tmp_path / "d.mcap").write_bytes(b"another recording")
    code, errors = _import(coco)
    assert code == 2 and "not the recording these labels were exported from" in errors[0]
    _no_yaml_written(tmp_path)
    (tmp_path / "d.mcap").write_bytes(b"a recording")  # the one exported: written beside it
    code, errors = _import(coco)
    assert code == 0 and (tmp_path / "d.annotations.yaml").is_file()


def test_an_annotation_file_its_reader_would_refuse_is_not_written(tmp_path: Path) -> None:
    coco, _ = _exported(tmp_path)
    doc = json.loads(coco.read_text())
    # A polygon of 60,000 vertices: 180,000 values, more than its reader accepts.
    ring = [v for k in range(60_000) for v in (300 + (k % 50) * 0.01, 300 + k * 1e-3)]
    t0 = time.monotonic()
    doc["annotations"][1]["segmentation"] = [ring]
    coco.write_text(json.dumps(doc))
    out = tmp_path / "big.annotations.yaml"
    code, errors = _import(coco, "-o", str(out))
    assert code == 2 and len(errors) == 1, errors
    assert "4194304" in errors[0] and "150000" in errors[0]
    assert not out.exists() and time.monotonic() - t0 < 10


def test_an_output_over_the_values_cap_is_refused_after_conversion(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Shapes whose count alone passes the early check: refused before the YAML is written.
    from sonarmap.pipeline.labels import destination

    coco, _ = _exported(tmp_path)
    monkeypatch.setattr(destination, "check_coco_values", lambda doc, where: None)
    monkeypatch.setattr("sonarmap.pipeline.labels.files.check_coco_values", lambda d, w: None)
    monkeypatch.setattr("sonarmap.pipeline.training.annotations.ANNOTATIONS_MAX_NODES", 20)
    out = tmp_path / "small.annotations.yaml"
    code, errors = _import(coco, "-o", str(out))
    assert code == 2 and "not written" in errors[0] and "over the 20 its reader" in errors[0]
    assert not out.exists()


def test_an_existing_output_that_is_not_utf8_needs_force(tmp_path: Path) -> None:
    coco, _ = _exported(tmp_path)
    out = tmp_path / "x.annotations.yaml"
    out.write_bytes(b"\xff\xfe\x00binary")
    code, errors = _import(coco, "-o", str(out))
    assert code == 2 and "--force" in errors[0]
    assert out.read_bytes() == b"\xff\xfe\x00binary"
    code, errors = _import(coco, "-o", str(out), "--force")
    assert code == 0 and out.read_text().startswith("format:")
    # The same labels again: nothing to replace, no --force needed.
    code, errors = _import(coco, "-o", str(out))
    assert code == 0


def test_geometry_records_the_recordings_identity(tmp_path: Path) -> None:
    _, geometry = _exported(tmp_path)
    doc = json.loads(geometry.read_text())
    assert doc["recording_identity"]["bytes"] == len(b"a recording")
    assert len(doc["recording_identity"]["head_sha256"]) == 64
    assert (tmp_path / "x" / GEOMETRY_FILE) == geometry
