"""Labels mean what they say (issue 52, root 3): a COCO file and its geometry.json are
validated against a schema before they are interpreted; duplicate or conflicting ids
and names, and fields of the wrong JSON type, are refused in one line naming the file
and the JSON path, exit 2."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from test_labels import LABELS, _frames
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.labels.files import GEOMETRY_FILE, export_labels
from sonarmap.schemas.classes import CLASS_IDS


def _exported(tmp_path: Path) -> tuple[Path, Path]:
    recording = tmp_path / "d.mcap"
    recording.write_bytes(b"a recording")
    frames = _frames([1_000_000_000, 2_000_000_000])
    shapes = {0: LABELS.keyframes[0].objects}
    done = export_labels(recording, tmp_path / "x", frames, {}, shapes, CLASS_IDS, 1.0)
    return done.coco, done.folder / GEOMETRY_FILE


def _edit(path: Path, change: Any) -> None:
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


def _import(coco: Path, *extra: str) -> tuple[int, list[str]]:
    res = CliRunner().invoke(app, ["label", "import", str(coco), *extra])
    assert "Traceback" not in res.output
    return res.exit_code, [ln for ln in res.output.splitlines() if ln.startswith("error:")]


def _piling_as_seawall(d: dict[str, Any]) -> None:
    d["categories"].append({"id": CLASS_IDS["cylindrical_piling"], "name": "seawall"})


@pytest.mark.parametrize(
    ("change", "where"),
    [
        (
            _piling_as_seawall,
            r"categories\[\d+\]\.id: \d+ is also categories\[\d+\]\.id \(\d+: "
            r"'cylindrical_piling' and \d+: 'seawall'\)",
        ),
        (
            lambda d: d["categories"].append({"id": 99, "name": "seawall"}),
            r"categories\[\d+\]\.name: 'seawall' is also categories\[\d+\]\.name",
        ),
        (lambda d: d["images"][1].update(id=1), r"images\[1\]\.id: 1 is also images\[0\]\.id"),
        (lambda d: d.update(images=5), r"images: Input should be a valid list, got int 5"),
        (lambda d: d["images"][0].update(id=[1]), r"images\[0\]\.id: .*got a list"),
        (lambda d: d["images"][0].update(id="1"), r"images\[0\]\.id: .*got a string '1'"),
        (lambda d: d["images"][0].update(id=True), r"images\[0\]\.id: .*got a boolean"),
        (lambda d: d["categories"][0].update(id=1.5), r"categories\[0\]\.id: .*got float 1.5"),
        (lambda d: d["annotations"][0].update(category_id=None), r"annotations\[0\]\.category_id"),
        (lambda d: d["annotations"][0].update(bbox="0 0 1 1"), r"annotations\[0\]\.bbox"),
        (lambda d: d["annotations"][1].update(id=1), r"annotations\[1\]\.id: 1 is also"),
        (lambda d: d.pop("images"), r"images: missing"),
        (lambda d: d["images"][0].pop("file_name"), r"images\[0\]\.file_name: missing"),
        (  # one image imported twice into Label Studio: two hash prefixes
            lambda d: d["images"][1].update(
                file_name="9f8e7d6c-" + d["images"][0]["file_name"].rsplit("/", 1)[-1]
            ),
            r"images\[1\]\.file_name '.*' is the exported image .* that images\[0\] names too",
        ),
        (  # 1e308 px became a polygon 5e306 m across
            lambda d: d["annotations"][0].update(segmentation=[[1e308, 0, 10, 10, 20, 0]]),
            r"segmentation\[0\]: the point \(1e\+308, 0\) px lies far outside the \d+ x \d+ image",
        ),
        (
            lambda d: d["annotations"][0].update(segmentation=[], bbox=[-9e9, 0, 10, 10]),
            r"bbox: the point \(-9e\+09, 0\) px lies far outside",
        ),
        (  # a tool that resized the images: the shapes' pixels no longer map to metres
            lambda d: d["images"][0].update(width=d["images"][0]["width"] // 2),
            r"images\[0\] is \d+ x \d+ pixels, exported at \d+ x \d+: the tool resized it",
        ),
    ],
)
def test_a_coco_file_of_the_wrong_shape_is_refused_naming_the_json_path(
    tmp_path: Path, change: Any, where: str
) -> None:
    coco, _ = _exported(tmp_path)
    _edit(coco, change)
    code, errors = _import(coco)
    assert code == 2 and len(errors) == 1, errors
    assert str(coco) in errors[0]
    assert pytest.importorskip("re").search(where, errors[0]), errors[0]
    assert not (tmp_path / "d.annotations.yaml").exists()


def _first_image(d: dict[str, Any]) -> dict[str, Any]:
    return d["images"][sorted(d["images"])[0]]


@pytest.mark.parametrize(
    ("change", "where"),
    [
        (lambda d: _first_image(d).update(t_ns="1000"), r"\.t_ns: .*got a string '1000'"),
        (lambda d: _first_image(d).pop("pixel_m"), r"\.pixel_m: missing"),
        (lambda d: _first_image(d).update(pixel_m=0), r"\.pixel_m: .*greater than 0"),
        (lambda d: _first_image(d).update(t_ns=-5), r"\.t_ns: .*greater than or equal to 0"),
        (lambda d: d.update(images=[]), r"images: .*valid dictionary, got a list"),
        (lambda d: d.update(time_tolerance_ms="2"), r"time_tolerance_ms: .*got a string"),
        (lambda d: d.update(recording=None), r"recording: .*got NoneType"),
    ],
)
def test_a_geometry_file_of_the_wrong_shape_is_refused_naming_the_json_path(
    tmp_path: Path, change: Any, where: str
) -> None:
    coco, geometry = _exported(tmp_path)
    _edit(geometry, change)
    code, errors = _import(coco)
    assert code == 2 and len(errors) == 1, errors
    assert str(geometry) in errors[0]
    assert pytest.importorskip("re").search(where, errors[0]), errors[0]


def test_tool_fields_of_their_own_are_kept_out_of_the_way(tmp_path: Path) -> None:
    coco, _ = _exported(tmp_path)

    def cvat(d: dict[str, Any]) -> None:
        for a in d["annotations"]:
            a["attributes"] = {"occluded": False}
            a["ignore"] = 0
        d["images"][0]["flickr_url"] = ""

    _edit(coco, cvat)
    code, errors = _import(coco)
    assert code == 0 and errors == []
