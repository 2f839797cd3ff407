"""`sonarmap label export` / `import`: keyframe images and COCO files in and out of a folder.

Export writes, into the folder:

- `images/<stem>_kf<id>_t<t_ns>.png`: each chosen keyframe's horizontal image as a
  Cartesian fan (`sonarmap.pipeline.labels.fan_image`);
- `<stem>.coco.json`: the COCO file (`sonarmap.pipeline.labels.coco`) with the images, the class
  table as categories and, optionally, shapes to start from;
- `geometry.json`: per image, the keyframe's time and the pixel-to-metre map, and the
  recording it came from. Import reads it back, so the COCO file itself carries nothing
  a labelling tool could drop.

Import turns the COCO file's polygons and boxes into the recording's annotation file
(`<stem>.annotations.yaml`, `sonarmap.schemas.annotations`).
"""

from __future__ import annotations

import io
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sonarmap.pipeline.engine.errors import ConfigError, SourceError
from sonarmap.pipeline.engine.text import one_line
from sonarmap.pipeline.engine.user_files import read_user_file, read_user_json
from sonarmap.pipeline.formats.atomic import atomic_output
from sonarmap.pipeline.labels.coco import ExportedImage, coco_document, objects_from_coco
from sonarmap.pipeline.labels.coco_schema import CocoDocument, CocoError, GeometryFile, validated
from sonarmap.pipeline.labels.destination import (
    annotation_destination,
    check_coco_values,
    check_size,
    check_values,
    recording_identity,
)
from sonarmap.pipeline.labels.fan_image import (
    FanGeometry,
    ImageTooLarge,
    fan_geometry,
    fan_image,
)
from sonarmap.schemas.annotations import AnnotatedKeyframe, AnnotatedObject, AnnotationFile
from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.schemas.sonar import KeyframeImages

__all__ = ["GEOMETRY_FILE", "ExportResult", "check_export_folder", "export_labels", "import_labels"]

GEOMETRY_FILE = "geometry.json"
GEOMETRY_FORMAT = "sonarmap-label-geometry/1"
COCO_MAX_BYTES = 8 << 20
"""Largest COCO or geometry file read: some 40,000 polygons, far beyond hand labelling
(the annotation file they become is itself capped at 4 MB); parsed and validated in
about a second and under 200 MB."""


@dataclass(frozen=True)
class ExportResult:
    folder: Path
    coco: Path
    images: int
    shapes: int


def _png(pixels: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(pixels, mode="L").save(buf, format="PNG", optimize=False)
    return buf.getvalue()


def _write(path: Path, data: bytes) -> None:
    with atomic_output(path) as f:
        f.write(data)


def check_export_folder(folder: Path, force: bool) -> None:
    """Refuse to export into a folder that holds an earlier export, unless `force`: a COCO
    file there may hold the labels a tool wrote back (the documented round trip exports
    into the same folder), and a new export renumbers the images that geometry.json maps.

    Raises:
        ConfigError: `folder` holds geometry.json or a `*.coco.json` file.
    """
    if force or not folder.is_dir():
        return
    found = sorted(p.name for p in folder.glob("*.coco.json"))
    if (folder / GEOMETRY_FILE).exists():
        found.insert(0, GEOMETRY_FILE)
    if found:
        raise ConfigError(
            f"{folder}: already holds an export ({', '.join(found[:3])}); its labels would be"
            " lost and its images renumbered: export into a new folder, or pass --force"
            " to replace it"
        )


def export_labels(
    recording: Path,
    folder: Path,
    frames: Sequence[KeyframeImages],
    times_ns: Mapping[int, int],
    objects: Mapping[int, Sequence[AnnotatedObject]],
    class_ids: Mapping[str, int],
    time_tolerance_ms: float,
    pixel_m: float | None = None,
) -> ExportResult:
    """Write the chosen keyframes' images, geometry and COCO file into `folder`.

    Args:
        recording: the recording (named in geometry.json, found again by import).
        folder: output folder (created).
        frames: the chosen keyframes.
        times_ns: keyframe id -> the time written for it (the keyframe's, or an existing
            annotation's within tolerance, so that its round trip is exact).
        objects: keyframe id -> shapes to start from (existing labels or the classifier's).
        class_ids: the class table (name -> id).
        time_tolerance_ms: written to geometry.json and back into the annotation file.
        pixel_m: pixel side [m] (None: each image's range resolution).
    """
    images_dir = folder / "images"
    try:  # every image's size first: nothing is written for a pixel side refused
        grids = [fan_geometry(frame.horizontal, pixel_m) for frame in frames]
    except ImageTooLarge as err:
        raise ConfigError(f"--pixel-m {pixel_m:g}: {err}") from None
    images_dir.mkdir(parents=True, exist_ok=True)
    exported = []
    for n, (frame, g) in enumerate(zip(frames, grids, strict=True), start=1):
        t_ns = int(times_ns.get(frame.keyframe_id, frame.t_ns))
        name = f"{recording.stem}_kf{frame.keyframe_id:05d}_t{t_ns}.png"
        _write(images_dir / name, _png(fan_image(frame.horizontal, g)))
        shapes = tuple(objects.get(frame.keyframe_id, ()))
        exported.append(ExportedImage(n, f"images/{name}", t_ns, frame.keyframe_id, g, shapes))
    doc = coco_document(exported, class_ids, f"sonarmap keyframes of {recording.name}")
    geometry = {
        "format": GEOMETRY_FORMAT,
        "recording": str(recording.resolve()),
        "recording_identity": recording_identity(recording),
        "time_tolerance_ms": time_tolerance_ms,
        "frame": "horizontal sonar fan plane: x forward, y left [m]; "
        "u = (y_left_m - y) / pixel_m, v = (x_top_m - x) / pixel_m (COCO pixels)",
        "images": {
            i.file_name: {"image_id": i.image_id, "t_ns": i.t_ns, "keyframe_id": i.keyframe_id}
            | i.geometry.to_json()
            for i in exported
        },
    }
    coco_path = folder / f"{recording.stem}.coco.json"
    _write(folder / GEOMETRY_FILE, (json.dumps(geometry, indent=1) + "\n").encode())
    _write(coco_path, (json.dumps(doc, indent=1) + "\n").encode())
    n_shapes = sum(len(i.objects) for i in exported)
    return ExportResult(folder, coco_path, len(exported), n_shapes)


def _read_json(path: Path, what: str) -> dict[str, Any]:
    doc = read_user_json(path, what, SourceError, COCO_MAX_BYTES)
    if not isinstance(doc, dict):
        raise SourceError(f"{path}: not a {what} (expected a JSON object)")
    return doc


def _valid(path: Path, raw: dict[str, Any], model: type[Any]) -> Any:
    """`raw` as `model` (`coco_schema`): one line naming the file and the JSON path."""
    try:
        return validated(raw, model)
    except CocoError as err:
        raise SourceError(f"{path}: {err}") from None


def _match(file_name: str, known: Mapping[str, Any]) -> str | None:
    """The exported image a tool's file name stands for: the same path, the same base
    name, or a base name the tool prefixed (Label Studio writes `<hash>-<name>`)."""
    if file_name in known:
        return file_name
    base = Path(file_name).name
    by_base = {Path(k).name: k for k in known}
    if base in by_base:
        return by_base[base]
    hits = [k for b, k in by_base.items() if base.endswith("-" + b) or base.endswith("_" + b)]
    return hits[0] if len(hits) == 1 else None


def import_labels(
    coco_path: Path,
    recording: Path | None = None,
    out: Path | None = None,
    *,
    force: bool = False,
    include_empty: bool = False,
    table: ClassTable = DEFAULT_TABLE,
) -> tuple[Path, AnnotationFile]:
    """Write the annotation file a COCO file describes; returns its path and content.
    Category names must be classes of `table` (the config's class table).

    Images without shapes are left out (not yet labelled) unless `include_empty` (labelled
    as holding no object). The annotation file goes to `out`, else beside the recording
    (`recording`, else the one geometry.json names) when it is the one exported
    (`destination.annotation_destination`).

    Raises:
        SourceError: the COCO file, geometry.json or a shape cannot be read (one line
            naming the file and entry), or the annotation file exists and `force` is off.
    """
    geometry_path = coco_path.parent / GEOMETRY_FILE
    geo = _read_json(geometry_path, "label geometry file (written by `sonarmap label export`)")
    if geo.get("format") != GEOMETRY_FORMAT:
        raise SourceError(f"{geometry_path}: not a {GEOMETRY_FORMAT} file")
    geometry = _valid(geometry_path, geo, GeometryFile)
    doc = _valid(coco_path, _read_json(coco_path, "COCO JSON file"), CocoDocument)
    check_coco_values(doc, coco_path)
    geometry_of: dict[int, FanGeometry] = {}
    t_of: dict[int, int] = {}
    named_by: dict[str, int] = {}
    for n, image in enumerate(doc.images):
        key = _match(image.file_name, geometry.images)
        where = f"{coco_path}: images[{n}]"
        if key is None:
            raise SourceError(
                f"{where}.file_name {one_line(image.file_name, 80)!r} is not "
                f"an image exported into {coco_path.parent}"
            )
        if key in named_by:  # an image imported twice into the tool (two hash prefixes)
            raise SourceError(
                f"{where}.file_name {one_line(image.file_name, 80)!r} is the exported image"
                f" {Path(key).name} that images[{named_by[key]}] names too: label each"
                " image once (merge their shapes into one)"
            )
        named_by[key] = n
        entry = geometry.images[key]
        size = (image.width, image.height)
        if None not in size and size != (entry.width_px, entry.height_px):
            # A tool that resized the images: its pixels no longer map to the fan's metres.
            raise SourceError(
                f"{where} is {image.width} x {image.height} pixels, exported at"
                f" {entry.width_px} x {entry.height_px}: the tool resized it, so its shapes"
                " cannot be placed; label the images at their exported size"
            )
        fields = {
            k: getattr(entry, k)
            for k in ("width_px", "height_px", "pixel_m", "x_top_m", "y_left_m")
        }
        geometry_of[image.id] = FanGeometry(**fields)
        t_of[image.id] = entry.t_ns
    try:
        objects = objects_from_coco(doc, geometry_of, table)
    except CocoError as err:
        raise SourceError(f"{coco_path}: {err}") from None
    keyframes = [
        AnnotatedKeyframe(t_ns=t_of[i], objects=tuple(objs))
        for i, objs in sorted(objects.items(), key=lambda kv: t_of[kv[0]])
        if objs or include_empty
    ]
    if not keyframes:
        raise SourceError(f"{coco_path}: no image holds a polygon or box (nothing to import)")
    annotations = AnnotationFile(
        time_tolerance_ms=geometry.time_tolerance_ms, keyframes=tuple(keyframes)
    )
    if out is None:
        out = annotation_destination(
            recording, geometry.recording, geometry.recording_identity, geometry_path
        )
    check_values(annotations.model_dump(mode="json", exclude_none=True), out)
    text = annotation_yaml(annotations)  # bounded: the values were counted first
    check_size(text, out)
    if not force and not _same_file(out, text.encode()):
        raise SourceError(f"{out}: exists with other labels; pass --force to replace it")
    _write(out, text.encode())
    return out, annotations


def _same_file(path: Path, data: bytes) -> bool:
    """True when `path` does not exist or holds exactly `data` (read guarded: a FIFO or
    device there is refused, a large file is not read)."""
    try:
        info = path.stat()
    except FileNotFoundError:
        return not path.is_symlink()  # a dangling link: something is there
    except OSError as err:
        raise SourceError(f"{path}: cannot read ({err.strerror})") from None
    if info.st_size != len(data):
        return False
    return read_user_file(path, "annotation file", SourceError, len(data)) == data


def annotation_yaml(annotations: AnnotationFile) -> str:
    """The annotation file's YAML text: flow style per shape, one shape a line."""
    import yaml

    doc = annotations.model_dump(mode="json", exclude_none=True)
    head = {k: v for k, v in doc.items() if k != "keyframes"}
    lines = [yaml.safe_dump(head, sort_keys=False).rstrip(), "keyframes:"]
    for kf in doc["keyframes"]:
        lines.append(f"  - t_ns: {kf['t_ns']}")
        if not kf["objects"]:
            lines.append("    objects: []")
            continue
        lines.append("    objects:")
        for obj in kf["objects"]:
            flow = yaml.safe_dump(obj, default_flow_style=True, sort_keys=False, width=10**6)
            lines.append(f"      - {flow.strip()}")
    return "\n".join(lines) + "\n"
