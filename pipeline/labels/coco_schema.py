"""The shape a COCO file and `geometry.json` must have before they are interpreted.

Validated with pydantic in strict mode (JSON types as written: an id is an integer, not
"3", 3.0, true or a list), then checked for the ids and names that must be unique: one
category id listed twice under two names would turn every box of the first class into
the second. Every refusal is one `CocoError` naming the JSON path (`images[3].id`).
Unknown fields are kept (tools add their own: CVAT `attributes`, Label Studio `ignore`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from sonarmap.pipeline.engine.text import one_line

__all__ = [
    "CocoAnnotation",
    "CocoCategory",
    "CocoDocument",
    "CocoError",
    "CocoImage",
    "GeometryFile",
    "GeometryImage",
    "validated",
]


class CocoError(ValueError):
    """A COCO file sonarmap cannot turn into annotations (the message names the entry)."""


class _Entry(BaseModel):
    model_config = ConfigDict(strict=True, extra="allow", frozen=True)


class CocoImage(_Entry):
    id: int
    file_name: str
    width: int | None = None
    height: int | None = None


class CocoCategory(_Entry):
    id: int
    name: str


class CocoAnnotation(_Entry):
    id: int | str | None = None
    image_id: int
    category_id: int
    # A dict is an RLE mask: kept so the import can say so (`coco._shapes`).
    segmentation: list[list[float]] | dict[str, Any] | None = None
    bbox: list[float] | None = None
    iscrowd: int | None = 0


class CocoDocument(_Entry):
    images: list[CocoImage]
    categories: list[CocoCategory] = Field(default_factory=list)
    annotations: list[CocoAnnotation] = Field(default_factory=list)


class GeometryImage(_Entry):
    """One exported image in geometry.json (`sonarmap.pipeline.labels.files`)."""

    image_id: int
    t_ns: int = Field(ge=0, lt=2**63)
    keyframe_id: int
    width_px: int = Field(ge=1)
    height_px: int = Field(ge=1)
    pixel_m: float = Field(gt=0.0, allow_inf_nan=False)
    x_top_m: float = Field(allow_inf_nan=False)
    y_left_m: float = Field(allow_inf_nan=False)


class GeometryFile(_Entry):
    format: str
    recording: str
    time_tolerance_ms: float = Field(default=1.0, gt=0.0, allow_inf_nan=False)
    images: dict[str, GeometryImage]
    recording_identity: dict[str, Any] | None = None


def _path(loc: Sequence[int | str]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif not part.isidentifier():
            out += f"[{one_line(repr(part), 80)}]"  # a dict key: an image's file name
        else:
            out += f".{part}" if out else part
    return one_line(out, 120) or "(top level)"


def _got(value: Any) -> str:
    kind = {dict: "an object", list: "a list", str: "a string", bool: "a boolean"}
    text = kind.get(type(value), type(value).__name__)
    if isinstance(value, (int, float, str)) and not isinstance(value, bool):
        text += f" {one_line(repr(value), 40)}"
    return text


def validated(raw: Any, model: type[Any]) -> Any:
    """`raw` validated as `model`; a `CocoError` naming the first bad JSON path."""
    try:
        doc = model.model_validate(raw)
    except ValidationError as err:
        first = err.errors()[0]
        # A union reports each branch; the path up to the union names the field.
        loc = [p for p in first["loc"] if not (isinstance(p, str) and "[" in p)]
        msg = str(first["msg"]).removeprefix("Value error, ")
        if first["type"] == "missing":
            raise CocoError(f"{_path(loc)}: missing") from None
        raise CocoError(f"{_path(loc)}: {msg[:120]}, got {_got(first.get('input'))}") from None
    if isinstance(doc, CocoDocument):
        _unique(doc)
    return doc


def _unique(doc: CocoDocument) -> None:
    """Refuse ids (and category names) given twice: which one is meant cannot be known."""
    for field, items, keys in (
        ("images", doc.images, ("id",)),
        ("categories", doc.categories, ("id", "name")),
        ("annotations", doc.annotations, ("id",)),
    ):
        for key in keys:
            first: dict[Any, int] = {}
            for n, item in enumerate(items):
                value = getattr(item, key)
                if value is None:
                    continue
                if value in first:
                    was = first[value]
                    raise CocoError(
                        f"{field}[{n}].{key}: {one_line(repr(value), 60)} is also "
                        f"{field}[{was}].{key}"
                        + (_names(doc, was, n) if field == "categories" else "")
                        + f" (each {key} must be listed once)"
                    )
                first[value] = n


def _names(doc: CocoDocument, a: int, b: int) -> str:
    x, y = doc.categories[a], doc.categories[b]
    if x.name == y.name and x.id == y.id:
        return ""
    return f" ({x.id}: {one_line(x.name, 40)!r} and {y.id}: {one_line(y.name, 40)!r})"
