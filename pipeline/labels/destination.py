"""Where `label import` may write, and what: outputs the user did not name are never
written, and an output its own reader would refuse is refused before it is written.

Export records the recording's identity in geometry.json (its size and a hash of its first
MiB, over every file of a bag folder): import writes beside that recording only when it
still exists and still has that identity. Otherwise (no recording named, moved, replaced,
an export older than the identity) it asks for `-o`.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.engine.text import one_line

__all__ = [
    "annotation_destination",
    "check_coco_values",
    "check_size",
    "check_values",
    "recording_identity",
]

_HEAD_BYTES = 1 << 20


def recording_identity(recording: Path) -> dict[str, Any] | None:
    """{"bytes": total size, "head_sha256": hash of each file's first MiB} of a recording
    file or bag folder; None when it is neither (nothing to recognise it by)."""
    from sonarmap.pipeline.readers.sources import dataset_fingerprint_parts

    try:
        files = dataset_fingerprint_parts(recording)
        digest = hashlib.sha256()
        total = 0
        for f in files:
            with f.open("rb") as fh:
                total += f.stat().st_size
                digest.update(fh.read(_HEAD_BYTES))
    except (OSError, SourceError):
        return None
    return {"bytes": total, "head_sha256": digest.hexdigest()}


def annotation_destination(
    named_recording: Path | None, exported_from: str, identity: dict[str, Any] | None, where: Path
) -> Path:
    """`<stem>.annotations.yaml` beside the recording the labels were exported from.

    Args:
        named_recording: `--recording` (else the one geometry.json names).
        exported_from: the recording geometry.json names.
        identity: the identity geometry.json recorded (None: an older export).
        where: geometry.json (named in messages).

    Raises:
        SourceError: no recording, or not the one exported: `-o` is needed.
    """
    recording = named_recording or (Path(exported_from) if exported_from.strip() else None)
    hint = "; name the annotation file to write with -o"
    if recording is None:
        raise SourceError(f"{where}: names no recording to write the annotation file beside{hint}")
    shown = one_line(str(recording), 200)
    if not recording.exists():
        raise SourceError(f"{where}: the recording {shown} does not exist{hint}")
    if identity is None:
        raise SourceError(
            f"{where}: records no identity of {shown} (an export by an older sonarmap), so "
            f"it cannot be told it is the recording these labels came from{hint}"
        )
    if recording_identity(recording) != identity:
        raise SourceError(
            f"{shown}: not the recording these labels were exported from (its size or "
            f"first bytes differ from what {where.name} recorded){hint}"
        )
    return recording.parent / f"{recording.stem}.annotations.yaml"


def _nodes(value: Any) -> int:
    """YAML nodes of a document as the bounded loader counts them (keys included)."""
    if isinstance(value, dict):
        return 1 + sum(1 + _nodes(v) for v in value.values())
    if isinstance(value, list | tuple):
        return 1 + sum(_nodes(v) for v in value)
    return 1


def _limits() -> tuple[int, int]:
    from sonarmap.pipeline.training.annotations import (
        ANNOTATIONS_MAX_BYTES,
        ANNOTATIONS_MAX_NODES,
    )

    return ANNOTATIONS_MAX_BYTES, ANNOTATIONS_MAX_NODES


def check_values(document: Any, out: Path) -> None:
    """Refuse an annotation document of more values than its reader accepts (checked
    before the YAML is written out, which takes time in proportion)."""
    max_bytes, max_nodes = _limits()
    nodes = _nodes(document)
    if nodes > max_nodes:
        raise SourceError(
            f"{one_line(str(out), 200)}: not written: the annotation file would hold {nodes} "
            f"values, over the {max_nodes} its reader accepts (an annotation file is at "
            f"most {max_bytes} bytes and {max_nodes} values: fewer shapes, or polygons of "
            "fewer vertices)"
        )


def check_size(text: str, out: Path) -> None:
    """Refuse an annotation file text over the size its reader accepts."""
    max_bytes, _ = _limits()
    size = len(text.encode())
    if size > max_bytes:
        raise SourceError(
            f"{one_line(str(out), 200)}: not written: the annotation file would be {size} "
            f"bytes, over the {max_bytes} its reader accepts (fewer or simpler shapes)"
        )


def check_coco_values(doc: Any, where: Path) -> None:
    """Refuse, before any shape is converted, a COCO file whose shapes alone would make an
    annotation file of more values than its reader accepts (a lower bound: 5 values per
    polygon and 3 per vertex, 13 per box)."""
    max_bytes, max_nodes = _limits()
    least = 0
    for ann in doc.annotations:
        polygons = ann.segmentation if isinstance(ann.segmentation, list) else []
        least += sum(5 + 3 * (len(p) // 2) for p in polygons) if polygons else 13
    if least > max_nodes:
        raise SourceError(
            f"{one_line(str(where), 200)}: its {len(doc.annotations)} shapes would make an "
            f"annotation file of at least {least} values, over the {max_nodes} its reader "
            f"accepts (an annotation file is at most {max_bytes} bytes and {max_nodes} values: "
            "fewer shapes, or polygons of fewer vertices)"
        )
