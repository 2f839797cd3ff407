"""Keys of per-keyframe work units (`sonarmap.stages.base.Units`): sha256 of what a unit
depends on, as canonical JSON, with arrays entered by the digest of their dtype, shape
and bytes. Pure: no I/O."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["array_digest", "json_array", "json_doc", "unit_key"]


def array_digest(*arrays: Any) -> str:
    """sha256 hex of the arrays' dtypes, shapes and C-order bytes, in order."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def unit_key(parts: Mapping[str, Any]) -> str:
    """sha256 hex of the canonical JSON of `parts` (sorted keys; floats as repr)."""
    text = json.dumps(parts, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def json_array(doc: Any) -> np.ndarray | None:
    """`doc` as a unit array (its UTF-8 JSON bytes), or None when JSON would not give it
    back unchanged (a value that is not plain JSON: such a doc is not cached)."""
    try:
        text = json.dumps(doc, allow_nan=False).encode()
    except (TypeError, ValueError):
        return None
    return np.frombuffer(text, np.uint8) if json.loads(text) == doc else None


def json_doc(array: Any) -> dict[str, Any]:
    """The doc a `json_array` holds."""
    return dict(json.loads(np.asarray(array, np.uint8).tobytes()))
