"""Labelling in standard tools: fan images, COCO export and import (issue 38, item 2)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.labels.fan_image import (
    fan_geometry,
    fan_image,
    metres_to_pixels,
    pixels_to_metres,
)
from sonarmap.pipeline.labels.files import annotation_yaml, export_labels, import_labels
from sonarmap.pipeline.training.annotations import load_annotations
from sonarmap.schemas.annotations import AnnotationFile
from sonarmap.schemas.classes import CLASS_IDS
from sonarmap.schemas.sonar import KeyframeImages, SonarPing

ROOT = Path(__file__).resolve().parents[1]

# An uneven beam table: 0.5 degree beams at the centre, 1.5 degree ones at the edges.
ANGLES = np.deg2rad(np.concatenate([np.arange(-60, -20, 1.5), np.arange(-20, 20, 0.5),
                                    np.arange(20, 60.1, 1.5)])).astype(np.float32)  # fmt: skip
RANGES = (np.arange(200) * 0.1 + 0.55).astype(np.float32)


def _ping(t_ns: int, bright: tuple[int, int] = (120, 40)) -> SonarPing:
    image = np.full((len(RANGES), len(ANGLES)), 3, np.uint8)
    image[bright] = 200
    return SonarPing(t_ns, "horizontal", image, RANGES, ANGLES)


def _rec(path: Path) -> Path:
    """A recording file to export from (import writes beside it only when it exists)."""
    path.write_bytes(b"a recording")
    return path


def _frames(times: list[int]) -> list[KeyframeImages]:
    return [KeyframeImages(k, t, _ping(t), _ping(t)) for k, t in enumerate(times)]


LABELS = AnnotationFile.model_validate(
    {
        "time_tolerance_ms": 2.5,
        "keyframes": [
            {
                "t_ns": 1_000_000_000,
                "objects": [
                    {"class_name": "cylindrical_piling", "box_m": {
                        "x_min_m": 5.4, "x_max_m": 6.3, "y_min_m": 2.5, "y_max_m": 3.4}},
                    {"class_name": "seawall",
                     "polygon_m": [[8.0, -4.0], [9.5, 2.0], [9.0, 2.2], [7.6, -3.9]]},
                ],
            },
            {"t_ns": 3_000_000_000, "objects": [
                {"class_name": "boat_hull", "polygon_m": [[12.25, -1.0], [14.0, -0.5],
                                                         [13.1, 1.75]]}]},
        ],
    }
)  # fmt: skip


def test_pixels_and_metres_are_inverse_and_forward_is_up_left_is_left() -> None:
    g = fan_geometry(_ping(0))
    xy = np.random.default_rng(3).uniform(-10, 20, (50, 2))
    assert np.allclose(pixels_to_metres(metres_to_pixels(xy, g), g), xy, atol=1e-12)
    ahead, left = metres_to_pixels(np.array([[10.0, 0.0], [5.0, 3.0]]), g)
    sonar = metres_to_pixels(np.zeros((1, 2)), g)[0]
    assert ahead[1] < sonar[1] and abs(ahead[0] - sonar[0]) < 1e-9  # forward is up
    assert left[0] < sonar[0]  # left of the vehicle is left in the image


def test_the_fan_image_puts_a_bright_cell_where_its_range_and_uneven_beam_say() -> None:
    for cell in ((120, 40), (30, 3), (190, len(ANGLES) - 2)):
        ping = _ping(0, cell)
        g = fan_geometry(ping)
        image = fan_image(ping, g)
        r, a = float(RANGES[cell[0]]), float(ANGLES[cell[1]])
        u, v = metres_to_pixels(np.array([[r * np.cos(a), r * np.sin(a)]]), g)[0]
        assert image[int(v), int(u)] == 255
        assert (image == 255).sum() < 0.01 * image.size
    corner = fan_image(ping, g)[-1, 0]  # behind and left of the sonar: outside the fan
    assert corner == 0


def test_export_then_import_gives_the_same_annotation_file(tmp_path: Path) -> None:
    recording = _rec(tmp_path / "dive.mcap")
    frames = _frames([1_000_000_000, 2_000_000_000, 3_000_000_000])
    times = {0: 1_000_000_000, 2: 3_000_000_000}
    shapes = {0: LABELS.keyframes[0].objects, 2: LABELS.keyframes[1].objects}
    done = export_labels(
        recording, tmp_path / "out", [frames[0], frames[2]], times, shapes, CLASS_IDS, 2.5
    )
    assert (done.images, done.shapes) == (2, 3)
    doc = json.loads(done.coco.read_text())
    assert {c["name"] for c in doc["categories"]} == set(CLASS_IDS) - {"none"}
    box, polygon = doc["annotations"][0], doc["annotations"][1]
    assert box["segmentation"] == [] and len(box["bbox"]) == 4 and box["iscrowd"] == 0
    assert len(polygon["segmentation"][0]) == 8 and polygon["area"] > 0
    path, imported = import_labels(done.coco)
    assert path == tmp_path / "dive.annotations.yaml"
    assert imported == LABELS
    assert path.read_text() == annotation_yaml(LABELS)
    assert load_annotations(path) == LABELS


def test_a_label_studio_export_with_renamed_files_and_unlabelled_images(tmp_path: Path) -> None:
    frames = _frames([1_000_000_000, 2_000_000_000])
    done = export_labels(_rec(tmp_path / "d.mcap"), tmp_path / "x", frames, {}, {}, CLASS_IDS, 1.0)
    doc = json.loads(done.coco.read_text())
    for image in doc["images"]:  # Label Studio: its own folder and a hash prefix
        image["file_name"] = "upload/7/1a2b3c4d-" + Path(image["file_name"]).name
    doc["annotations"] = [
        {"id": 9, "image_id": 2, "category_id": CLASS_IDS["truss"], "iscrowd": 0,
         "segmentation": [[100, 100, 140, 100, 140, 130]], "bbox": [100, 100, 40, 30]}
    ]  # fmt: skip
    done.coco.write_text(json.dumps(doc))
    _, labels = import_labels(done.coco)
    assert [k.t_ns for k in labels.keyframes] == [2_000_000_000]
    assert labels.keyframes[0].objects[0].class_name == "truss"
    _, with_empty = import_labels(done.coco, force=True, include_empty=True)
    assert [len(k.objects) for k in with_empty.keyframes] == [0, 1]


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d["annotations"][0].update(segmentation={"counts": "x", "size": [2, 2]}), "RLE"),
        (lambda d: d["annotations"][0].update(category_id=77), "category_id 77"),
        (lambda d: d["images"][0].update(file_name="other.png"), "other.png"),
        (lambda d: d["annotations"][0].update(segmentation=[[1, 2, 3, 4]]), "3 or more"),
        (lambda d: d["annotations"][0].update(image_id=5), "image_id 5"),
    ],
)
def test_a_coco_file_that_cannot_be_read_is_refused_naming_the_entry(
    tmp_path: Path, change: Any, message: str
) -> None:
    frames = _frames([1_000_000_000])
    shapes = {0: LABELS.keyframes[0].objects}
    done = export_labels(
        _rec(tmp_path / "d.mcap"), tmp_path / "x", frames, {}, shapes, CLASS_IDS, 1.0
    )
    doc = json.loads(done.coco.read_text())
    change(doc)
    done.coco.write_text(json.dumps(doc))
    with pytest.raises(SourceError, match=message) as err:
        import_labels(done.coco)
    assert str(done.coco) in str(err.value) and "\n" not in str(err.value)


def test_import_never_overwrites_other_labels_without_force(tmp_path: Path) -> None:
    frames = _frames([1_000_000_000])
    shapes = {0: LABELS.keyframes[0].objects}
    done = export_labels(
        _rec(tmp_path / "d.mcap"), tmp_path / "x", frames, {}, shapes, CLASS_IDS, 1.0
    )
    existing = tmp_path / "d.annotations.yaml"
    existing.write_text("format: sonarmap-annotations/1\nkeyframes: []\n")
    result = CliRunner().invoke(app, ["label", "import", str(done.coco)])
    assert result.exit_code == 2 and "--force" in result.output
    assert existing.read_text().endswith("keyframes: []\n")
    result = CliRunner().invoke(app, ["label", "import", str(done.coco), "--force", "--json"])
    assert result.exit_code == 0 and json.loads(result.stdout)["objects"] == 2


def test_one_command_each_way_on_a_simulated_recording(tmp_path: Path) -> None:
    from sonarmap.pipeline.formats.simulation import write_simulation
    from sonarmap.sim.config import SimConfig
    from sonarmap.sim.dataset import simulate
    from sonarmap.sim.scene import load_scene

    scene = ROOT / "configs" / "scenes" / "tiny.yaml"
    base = SimConfig()
    mission = base.mission.model_copy(update={"n_goals": 2, "duration_s": 20.0})
    run = simulate(load_scene(scene), base.model_copy(update={"mission": mission}), 3)
    recording = tmp_path / "tiny.mcap"
    write_simulation(run, recording, scene_yaml=scene.read_text())
    store, out = tmp_path / "store", tmp_path / "labels"
    cli = CliRunner()
    result = cli.invoke(app, ["label", "export", str(recording), "-o", str(out), "-k", "0,2",
                              "--store", str(store), "--json"])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["images"] == 2 and len(list(out.glob("images/*.png"))) == 2
    coco = out / "tiny.coco.json"
    doc = json.loads(coco.read_text())
    doc["annotations"] = [
        {"id": 1, "image_id": 1, "category_id": CLASS_IDS["seawall"], "iscrowd": 0,
         "segmentation": [], "bbox": [10, 20, 30, 40]}
    ]  # fmt: skip
    coco.write_text(json.dumps(doc))
    result = cli.invoke(app, ["label", "import", str(coco)])
    assert result.exit_code == 0, result.output
    labels = load_annotations(tmp_path / "tiny.annotations.yaml")
    assert len(labels.keyframes) == 1 and labels.keyframes[0].objects[0].class_name == "seawall"
    # Exporting again into the folder would lose the labels the tool wrote back into it.
    labelled = coco.read_bytes()
    again = cli.invoke(app, ["label", "export", str(recording), "-o", str(out), "--every", "2",
                             "--store", str(store)])  # fmt: skip
    assert again.exit_code == 2 and "already holds an export" in again.stderr
    assert coco.read_bytes() == labelled
    missing = cli.invoke(app, ["label", "export", str(recording), "-o", str(out), "-k", "999",
                               "--store", str(store), "--force"])  # fmt: skip
    assert missing.exit_code == 2 and "no keyframe 999" in missing.output
