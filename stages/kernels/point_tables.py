"""Point tables of the class models' stages: per-object parts of fused and inferred
points (`tag_points`) concatenated into one sorted table (`points_table`), for
`points.parquet` (stage `infer`) and `submap_points.parquet` (stage `submaps`)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.schemas.points import POINTS_SCHEMA

__all__ = ["points_table", "tag_points"]


def tag_points(
    pts: dict[str, np.ndarray],
    keyframe_id: int,
    object_id: int | np.ndarray,
    class_name: str,
    source: str,
) -> dict:
    n = pts["range_m"].size
    return {
        **pts,
        "keyframe_id": np.full(n, keyframe_id, dtype=np.int64),
        "object_id": np.broadcast_to(np.asarray(object_id, dtype=np.int64), (n,)),
        # strings per part, not per point: `_table` expands them in Arrow
        "class_name": (class_name, n),
        "source": (source, n),
    }


def points_table(
    parts: list[dict[str, Any]],
    schema: pa.Schema = POINTS_SCHEMA,
    sort_keys: tuple[str, ...] = (
        "keyframe_id",
        "object_id",
        "source",
        "range_m",
        "bearing_rad",
        "z_m",
    ),
) -> pa.Table:
    """Concatenate point dicts (`tag_points`) into a sorted table of `schema`."""
    cols = {}
    for f in schema:
        values = [p[f.name] for p in parts]
        if f.type == pa.string():
            names, codes = np.unique([v[0] for v in values], return_inverse=True)
            repeats = np.array([v[1] for v in values], dtype=np.int64)
            cols[f.name] = (
                pa.array(names.tolist(), pa.string()).take(np.repeat(codes.reshape(-1), repeats))
                if values
                else pa.array([], pa.string())
            )
            continue
        data = np.concatenate(values) if values else np.empty(0)
        cols[f.name] = pa.array(data, f.type)
    table = pa.table(cols, schema=schema)
    return table.sort_by([(k, "ascending") for k in sort_keys])
