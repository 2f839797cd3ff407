"""The side views of `side_view.png`: the pilings with the most map points near them."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from schemas.classes import CLASS_IDS, PILING_CLASSES
from stages.evaluate.report import SidePanel
from stages.kernels.ply import Mesh
from stages.kernels.voxels import map_xyz

__all__ = ["side_panels"]


def side_panels(
    map_table: pa.Table, mesh: Mesh, samples: np.ndarray, n_panels: int
) -> list[SidePanel]:
    """Side views (x - centre vs z) of the pilings with the most map points nearby."""
    oid = mesh.vertex_properties.get("object_id")
    cls = mesh.vertex_properties.get("class_id")
    if oid is None or cls is None:
        return []
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
    panels = []
    for count, obj, centre, radius, near in candidates[:n_panels]:
        if count == 0:
            break
        truth = samples[np.linalg.norm(samples[:, :2] - centre, axis=1) <= radius]
        truth = truth[truth[:, 2] <= 0.0]

        def hz(p: np.ndarray, c: np.ndarray = centre) -> np.ndarray:
            return np.stack([p[:, 0] - c[0], p[:, 2]], axis=1)

        panels.append(
            SidePanel(
                f"object {obj} at ({centre[0]:.1f}, {centre[1]:.1f})",
                "x - centre",
                hz(pts[near & (source == "fused")]),
                hz(pts[near & (source == "inferred")]),
                hz(truth),
            )
        )
    return panels
