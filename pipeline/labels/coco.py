"""COCO object-detection JSON <-> sonarmap annotations (pure: dicts in, dicts out).

The fields written are those of the COCO "object detection" data format
(https://cocodataset.org/#format-data): `images` (id, file_name, width, height),
`categories` (id, name, supercategory), `annotations` (id, image_id, category_id,
segmentation as a list of polygons [x1, y1, x2, y2, ...], bbox [x, y, width, height],
area, iscrowd), plus `info` and `licenses`. CVAT and Label Studio both import and export
this format. Coordinates are pixels of the exported fan image (`sonarmap.pipeline.labels.fan_image`).

A sonarmap box becomes a COCO annotation with a bbox and an empty segmentation (the tools
show it as a rectangle); a polygon becomes a one-polygon segmentation with its bbox.
Category ids are the class ids of the class table (COCO needs ids >= 1; "none" is not a
category).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import ValidationError

from sonarmap.pipeline.labels.coco_schema import CocoDocument, CocoError, validated
from sonarmap.pipeline.labels.fan_image import FanGeometry, metres_to_pixels, pixels_to_metres
from sonarmap.schemas.annotations import AnnotatedObject
from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable

__all__ = ["CocoError", "ExportedImage", "coco_document", "objects_from_coco"]

METRE_DECIMALS = 6
"""Imported metres are rounded to a micrometre: far below any sonar pixel, and enough that
a shape exported and imported again reads back as the numbers that were typed."""


@dataclass(frozen=True)
class ExportedImage:
    """One exported keyframe image: its COCO entry, its geometry and its shapes."""

    image_id: int
    file_name: str
    t_ns: int
    keyframe_id: int
    geometry: FanGeometry
    objects: Sequence[AnnotatedObject] = ()


def _polygon_px(vertices_m: Sequence[tuple[float, float]], g: FanGeometry) -> list[float]:
    return [float(v) for v in metres_to_pixels(np.asarray(vertices_m), g).ravel()]


def _bbox(flat: Sequence[float]) -> list[float]:
    u, v = np.asarray(flat[0::2], np.float64), np.asarray(flat[1::2], np.float64)
    return [float(u.min()), float(v.min()), float(u.max() - u.min()), float(v.max() - v.min())]


def _shoelace(flat: Sequence[float]) -> float:
    u, v = np.asarray(flat[0::2], np.float64), np.asarray(flat[1::2], np.float64)
    return float(0.5 * abs(np.dot(u, np.roll(v, -1)) - np.dot(v, np.roll(u, -1))))


def _annotation(obj: AnnotatedObject, g: FanGeometry, category_id: int) -> dict[str, Any]:
    if obj.polygon_m is not None:
        flat = _polygon_px(obj.polygon_m, g)
        bbox, segmentation, area = _bbox(flat), [flat], _shoelace(flat)
    else:
        bbox = _bbox(_polygon_px(obj.vertices_m(), g))
        segmentation, area = [], bbox[2] * bbox[3]
    return {
        "category_id": category_id,
        "segmentation": segmentation,
        "bbox": bbox,
        "area": area,
        "iscrowd": 0,
    }


def coco_document(
    images: Sequence[ExportedImage], class_ids: Mapping[str, int], description: str
) -> dict[str, Any]:
    """The COCO JSON of exported images and their (pre-)labels."""
    categories = [
        {"id": cid, "name": name, "supercategory": "structure"}
        for name, cid in sorted(class_ids.items(), key=lambda kv: kv[1])
        if cid > 0
    ]
    annotations: list[dict[str, Any]] = []
    for image in images:
        for obj in image.objects:
            row = _annotation(obj, image.geometry, class_ids[obj.class_name])
            annotations.append({"id": len(annotations) + 1, "image_id": image.image_id, **row})
    return {
        "info": {"description": description, "version": "1.0"},
        "licenses": [],
        "images": [
            {
                "id": i.image_id,
                "file_name": i.file_name,
                "width": i.geometry.width_px,
                "height": i.geometry.height_px,
            }
            for i in images
        ],
        "categories": categories,
        "annotations": annotations,
    }


def _rounded(xy: np.ndarray) -> list[tuple[float, float]]:
    return [(round(float(x), METRE_DECIMALS), round(float(y), METRE_DECIMALS)) for x, y in xy]


def _numbers(value: Any, what: str, count: int | None = None) -> list[float]:
    ok = isinstance(value, list) and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
    )
    if not ok or (count is not None and len(value) != count):
        raise CocoError(f"{what}: expected {count or 'a list of'} numbers")
    return [float(v) for v in value]


def _on_the_image(uv: np.ndarray, g: FanGeometry, what: str) -> np.ndarray:
    """`uv` [px], refused when a point lies more than the image's own size beyond its edges:
    no tool draws there, and 1e308 px became a polygon 5e306 m across."""
    w, h = g.width_px, g.height_px
    far = ~(
        (uv[:, 0] >= -w) & (uv[:, 0] <= 2 * w) & (uv[:, 1] >= -h) & (uv[:, 1] <= 2 * h)
    )  # NaN is far too
    if far.any():
        u, v = uv[int(np.argmax(far))]
        raise CocoError(f"{what}: the point ({u:.6g}, {v:.6g}) px lies far outside the {w} x {h} image")
    return uv


def _shapes(ann: Mapping[str, Any], g: FanGeometry, where: str) -> list[dict[str, Any]]:
    """The sonarmap shapes ({"polygon_m": ...} or {"box_m": ...}) of one COCO annotation."""
    segmentation = ann.get("segmentation") or []
    if isinstance(segmentation, dict) or ann.get("iscrowd") == 1:
        raise CocoError(f"{where}: an RLE mask (iscrowd) is not a shape; export polygons or boxes")
    if not isinstance(segmentation, list):
        raise CocoError(f"{where}.segmentation: expected a list of polygons")
    shapes = []
    for k, poly in enumerate(segmentation):
        flat = _numbers(poly, f"{where}.segmentation[{k}]")
        if len(flat) < 6 or len(flat) % 2:
            raise CocoError(f"{where}.segmentation[{k}]: a polygon needs 3 or more (x, y) pairs")
        uv = _on_the_image(np.reshape(flat, (-1, 2)), g, f"{where}.segmentation[{k}]")
        xy = pixels_to_metres(uv, g)
        shapes.append({"polygon_m": _rounded(xy)})
    if shapes:
        return shapes
    u, v, w, h = _numbers(ann.get("bbox"), f"{where}.bbox", 4)
    box = _on_the_image(np.array([[u, v], [u + w, v + h]]), g, f"{where}.bbox")
    corners = pixels_to_metres(box, g)
    (x_hi, y_hi), (x_lo, y_lo) = _rounded(corners)
    return [{"box_m": {"x_min_m": x_lo, "x_max_m": x_hi, "y_min_m": y_lo, "y_max_m": y_hi}}]


def objects_from_coco(
    doc: Mapping[str, Any] | CocoDocument,
    geometry_of: Mapping[int, FanGeometry],
    table: ClassTable = DEFAULT_TABLE,
) -> dict[int, list[AnnotatedObject]]:
    """{COCO image id: its objects, in annotation order} for the images in geometry_of;
    each category name must be a class of `table` (the config's class table).

    Raises:
        CocoError: an annotation's category, image or shape cannot be read (naming it).
    """
    coco = doc if isinstance(doc, CocoDocument) else validated(doc, CocoDocument)
    names = {c.id: c.name for c in coco.categories}
    out: dict[int, list[AnnotatedObject]] = {i: [] for i in geometry_of}
    for n, entry in enumerate(coco.annotations):
        ann = entry.model_dump()
        where = f"annotations[{n}] (id {ann.get('id')!r:.20})"
        image_id = ann["image_id"]
        if image_id not in out:
            raise CocoError(f"{where}: image_id {image_id!r:.20} is not an exported image")
        name = names.get(ann["category_id"])
        if name is None:
            raise CocoError(f"{where}: category_id {ann['category_id']!r:.20} is not listed")
        for shape in _shapes(ann, geometry_of[image_id], where):
            try:
                obj = AnnotatedObject.model_validate(
                    {"class_name": name, **shape}, context={"classes": table}
                )
                out[image_id].append(obj)
            except ValidationError as err:
                first = str(err.errors()[0]["msg"]).removeprefix("Value error, ")
                raise CocoError(f"{where}: {first[:300]}") from None
    return out
