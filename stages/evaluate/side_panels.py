"""The data of `side_view.png` (`side_view.parquet`): the pilings with the most map points
near them, seen from the side."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from sonarmap.schemas.classes import CLASS_IDS, PILING_CLASSES
from sonarmap.schemas.figures import SIDE_VIEW_KINDS, SIDE_VIEW_SCHEMA
from sonarmap.stages.kernels.ply import Mesh
from sonarmap.stages.kernels.voxels import map_xyz

__all__ = ["side_panels"]


def side_panels(
    map_table: pa.Table, mesh: Mesh, samples: np.ndarray, n_panels: int
) -> pa.Table | None:
    """Side views (x - centre vs z) of the pilings with the most map points nearby, as
    `side_view.parquet` rows (`sonarmap.schemas.figures.SIDE_VIEW_SCHEMA`); None: no such piling."""
    oid = mesh.vertex_properties.get("object_id")
    cls = mesh.vertex_properties.get("class_id")
    if oid is None or cls is None:
        return None
    piling = np.isin(cls, [CLASS_IDS[c] for c in PILING_CLASSES])
    pts = map_xyz(map_table, "semantic")
    source = np.asarray(map_table.column("source").to_pylist(), dtype=object)
    candidates = []
    for obj in np.unique(oid[piling]):
        v = mesh.vertices[oid == obj]
        centre = v[:, :2].mean(axis=0)
        radius = float(np.max(np.linalg.norm(v[:, :2] - centre, axis=1))) + 0.3
        near = np.linalg.norm(pts[:, :2] - centre, axis=1) <= radius
        candidates.append((-int(near.sum()), int(obj), centre, radius, near))
    candidates.sort(key=lambda c: (c[0], c[1]))
    parts: list[tuple[int, str, str, np.ndarray]] = []
    for panel, (count, obj, centre, radius, near) in enumerate(candidates[:n_panels]):
        if count == 0:
            break
        truth = samples[np.linalg.norm(samples[:, :2] - centre, axis=1) <= radius]
        truth = truth[truth[:, 2] <= 0.0]
        title = f"object {obj} at ({centre[0]:.1f}, {centre[1]:.1f})"
        kinds = (pts[near & (source == "fused")], pts[near & (source == "inferred")], truth)
        for kind, p in zip(SIDE_VIEW_KINDS, kinds, strict=True):
            parts.append((panel, title, kind, np.stack([p[:, 0] - centre[0], p[:, 2]], axis=1)))
    return _table(parts) if parts else None


def _table(parts: list[tuple[int, str, str, np.ndarray]]) -> pa.Table:
    """side_view.parquet rows from (panel, title, kind, (n, 2) h z) blocks, in order."""
    sizes = [len(hz) for *_, hz in parts]
    hz = np.concatenate([hz for *_, hz in parts]).reshape(-1, 2)
    return pa.table(
        {
            "panel": np.repeat([p for p, *_ in parts], sizes).astype(np.int32),
            "title": pa.array(np.repeat([t for _, t, *_ in parts], sizes).tolist(), pa.string()),
            "axis_label": pa.array(["x - centre"] * len(hz), pa.string()),
            "kind": pa.array(np.repeat([k for _, _, k, _ in parts], sizes).tolist(), pa.string()),
            "h_m": hz[:, 0],
            "z_m": hz[:, 1],
        },
        schema=SIDE_VIEW_SCHEMA,
    )
