"""Numeric codes of map points' class and source, as the PLY and Foxglove outputs carry
them: viewers colour and filter by numbers, not strings."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from sonarmap.schemas.classes import DEFAULT_TABLE, UNKNOWN_CLASS, ClassTable
from sonarmap.schemas.map import NO_CLASS
from sonarmap.schemas.submaps import KEYFRAME_FRAME_ID

__all__ = ["NO_CLASS_ID", "SOURCE_IDS", "UNKNOWN_CLASS_ID", "class_ids", "source_ids"]

SOURCE_IDS: dict[str, int] = {"fused": 0, "inferred": 1, "submap": 2}
"""0: fused in a keyframe, 1: inferred in a keyframe, 2: from a dense submap frame."""
NO_CLASS_ID = 254
"""class id of a point of no classified object (`sonarmap.schemas.map.NO_CLASS`)."""
UNKNOWN_CLASS_ID = 255
"""class id of a point the classifier was not confident about, or of an unlisted class."""


def class_ids(names: pa.Array | pa.ChunkedArray, table: ClassTable = DEFAULT_TABLE) -> np.ndarray:
    """(n,) uint8 label id in the class table of each class name (254 none, 255 unknown)."""
    ids = {**table.ids, NO_CLASS: NO_CLASS_ID, UNKNOWN_CLASS: UNKNOWN_CLASS_ID}
    encoded = pc.dictionary_encode(names)
    if isinstance(encoded, pa.ChunkedArray):
        encoded = encoded.combine_chunks()
    # one lookup per distinct name, then a gather: no per-point Python
    lookup = np.array(
        [ids.get(n, UNKNOWN_CLASS_ID) for n in encoded.dictionary.to_pylist()] or [0], np.uint8
    )
    return lookup[encoded.indices.to_numpy(zero_copy_only=False).astype(np.int64)]


def source_ids(source: pa.Array | pa.ChunkedArray, frame_id: np.ndarray) -> np.ndarray:
    """(n,) uint8 SOURCE_IDS code of each map row from its source and submap frame_id."""
    out = np.where(
        pc.equal(source, "inferred").to_numpy(zero_copy_only=False),
        SOURCE_IDS["inferred"],
        SOURCE_IDS["fused"],
    ).astype(np.uint8)
    out[np.asarray(frame_id) != KEYFRAME_FRAME_ID] = SOURCE_IDS["submap"]
    return out
