"""Per-class coverage and error of the standard and semantic maps (paper Table I, by class).

The paper's Table I counts 10 cm voxels of the whole map. Where a gain comes from (or
does not) shows only class by class, so every map point is given the *true* class of
the ground-truth surface nearest to it (the mesh's faces carry `class_id`; a face's
class is its first vertex's, as in `mesh_metrics.surface_samples`), and for every
class present and for "all structure" (every class but the seafloor) both maps report:

- voxels: occupied `voxel_size_m` voxels (floor(x / size), as `voxelize` counts them)
  holding a point of the class;
- accurate voxels: voxels holding at least one point of the class within `tolerance_m`
  of the true surface, so noise cannot inflate coverage;
- completeness: fraction of the class's visible surface samples (the rule of
  `mesh_metrics`: near-vertical faces below the water, inside some keyframe's field of
  view, not occluded) within `tolerance_m` of a map point;
- median error of the class's points, and for the inferred points alone.

By *assigned* class (the class the classifier gave the point's object, `class_name` of
the map) it also reports the median error of the fused and of the inferred points and
their ratio (`assigned_classes`): the per-class error budget that decides which classes
`infer` models by default (`sonarmap.stages.infer.config.DEFAULT_CLASSES`) is judged on these.

Errors and classes are taken at the positions the evaluation judges (after the SLAM
trajectory's SE(2) alignment when there is one, `frame`), voxels at the map's own
positions, so the voxel counts add up to `summary.json`'s.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.stages.kernels.lazy import lazy
from sonarmap.stages.kernels.mesh_metrics import nearest_distance, surface_samples
from sonarmap.stages.kernels.ply import Mesh
from sonarmap.stages.kernels.voxels import map_xyz, voxel_keys

o3d = lazy("open3d")

__all__ = [
    "ALL_STRUCTURE",
    "assigned_class_errors",
    "class_table",
    "face_classes",
    "nearest_surface_class",
    "per_class_metrics",
    "remember_last",
]

ALL_STRUCTURE = "all_structure"
"""Name of the aggregate of every class but the seafloor."""


def _seafloor_id(table: ClassTable) -> int:
    return table.ids.get("seafloor", -1)


def face_classes(mesh: Mesh) -> np.ndarray:
    """(t,) int64 class id of every mesh face (its first vertex's; 0 without labels)."""
    cls = mesh.vertex_properties.get("class_id")
    if cls is None:
        return np.zeros(len(mesh.triangles), dtype=np.int64)
    return np.asarray(cls, dtype=np.int64)[mesh.triangles[:, 0]]


def nearest_surface_class(
    scene: o3d.t.geometry.RaycastingScene, faces_class_id: np.ndarray, points_m: np.ndarray
) -> np.ndarray:
    """(n,) int64 class id of the ground-truth face nearest to each (n, 3) point."""
    pts = np.asarray(points_m, dtype=np.float32).reshape(-1, 3)
    if len(pts) == 0:
        return np.zeros(0, dtype=np.int64)
    closest = scene.compute_closest_points(o3d.core.Tensor(pts), nthreads=0)
    face = closest["primitive_ids"].numpy().astype(np.int64)
    return faces_class_id[np.clip(face, 0, len(faces_class_id) - 1)]


def _unique_voxels(keys: np.ndarray, mask: np.ndarray) -> int:
    return int(np.unique(keys[mask]).size) if mask.any() else 0


def _median(values: np.ndarray) -> float | None:
    return float(np.median(values)) if values.size else None


def _map_figures(
    mask: np.ndarray, keys: np.ndarray, error_m: np.ndarray, tol: float
) -> dict[str, Any]:
    return {
        "points": int(mask.sum()),
        "voxels": _unique_voxels(keys, mask),
        "accurate_voxels": _unique_voxels(keys, mask & (error_m <= tol)),
        "median_error_m": _median(error_m[mask]),
    }


def class_table(
    point_class_id: np.ndarray,
    error_m: np.ndarray,
    is_fused: np.ndarray,
    voxel_ijk: np.ndarray,
    sample_class_id: np.ndarray,
    sample_distance_m: dict[str, np.ndarray],
    tolerance_m: float,
    table: ClassTable = DEFAULT_TABLE,
) -> dict[str, dict[str, Any]]:
    """Figures of both maps for every class present and for all structure.

    Args:
        point_class_id: (n,) true class of each map point (`nearest_surface_class`).
        error_m: (n,) distance of each point to the true surface [m].
        is_fused: (n,) True for standard-map points (source "fused").
        voxel_ijk: (n, 3) int64 voxel index of each point.
        sample_class_id: (s,) class of each visible surface sample.
        sample_distance_m: {"standard"|"semantic": (s,) distance from each visible
            sample to the nearest point of that map (inf beyond the tolerance)}.
        tolerance_m: accuracy / completeness distance [m].
        table: the class table naming the ids.

    Returns:
        {class name: {"standard": {...}, "semantic": {...}, "inferred": {...},
        "visible_samples": int}}, classes in id order, then "all_structure".
    """
    present = set(np.unique(point_class_id).tolist()) | set(np.unique(sample_class_id).tolist())
    groups = [
        (table.name_of(c), point_class_id == c, sample_class_id == c) for c in sorted(present)
    ]
    floor = _seafloor_id(table)
    groups.append((ALL_STRUCTURE, (point_class_id != floor), (sample_class_id != floor)))
    keys = voxel_keys(voxel_ijk)
    out: dict[str, dict[str, Any]] = {}
    for name, of_class, samples in groups:
        if name == table.name_of(0) and not of_class.any():
            continue
        entry: dict[str, Any] = {}
        for map_name, in_map in (("standard", is_fused), ("semantic", np.ones_like(is_fused))):
            entry[map_name] = _map_figures(of_class & in_map, keys, error_m, tolerance_m)
            d = sample_distance_m[map_name][samples]
            entry[map_name]["completeness"] = float(np.mean(d <= tolerance_m)) if d.size else None
        inferred = of_class & ~is_fused
        entry["inferred"] = {
            "points": int(inferred.sum()),
            "median_error_m": _median(error_m[inferred]),
        }
        entry["visible_samples"] = int(samples.sum())
        out[name] = entry
    return out


def remember_last(
    visible: Callable[[np.ndarray], np.ndarray],
) -> Callable[[np.ndarray], np.ndarray]:
    """`visible` that returns its last answer again for equal samples: every
    `per_class_metrics` call of one evaluation draws the same samples (same mesh, density
    and seed), and ray casting them is its most expensive step."""
    last: list[tuple[np.ndarray, np.ndarray]] = []

    def remembered(samples: np.ndarray) -> np.ndarray:
        if last and last[0][0].shape == samples.shape and np.array_equal(last[0][0], samples):
            return last[0][1].copy()
        last[:] = [(samples.copy(), visible(samples))]
        return last[0][1].copy()

    return remembered


def assigned_class_errors(map_table: pa.Table, error_m: np.ndarray) -> dict[str, Any]:
    """Median error of the fused and inferred points of every assigned class, and the
    inferred over the fused median (None where either set is empty)."""
    names = np.asarray(map_table.column("class_name").to_pylist(), dtype=object)
    source = np.asarray(map_table.column("source").to_pylist(), dtype=object)
    out: dict[str, Any] = {}
    for name in sorted(set(names.tolist())):
        of_class = names == name
        fused = _median(error_m[of_class & (source == "fused")])
        inferred = _median(error_m[of_class & (source == "inferred")])
        out[name] = {
            "fused_points": int((of_class & (source == "fused")).sum()),
            "inferred_points": int((of_class & (source == "inferred")).sum()),
            "fused_median_error_m": fused,
            "inferred_median_error_m": inferred,
            "inferred_over_fused": inferred / fused if inferred is not None and fused else None,
        }
    return out


def per_class_metrics(
    map_table: pa.Table,
    mesh: Mesh,
    scene: o3d.t.geometry.RaycastingScene,
    xyz_m: np.ndarray,
    error_m: np.ndarray,
    voxel_size_m: float,
    visible: Callable[[np.ndarray], np.ndarray],
    tolerance_m: float,
    samples_per_m2: float,
    seed: int,
    table: ClassTable = DEFAULT_TABLE,
) -> dict[str, Any]:
    """Coverage and error of both maps class by class (see the module docstring).

    Args:
        map_table: map.parquet (voxels are counted at its own positions).
        xyz_m, error_m: (n, 3) positions and (n,) errors at which the map is judged.
        visible: (s, 3) surface samples -> (s,) bool, the visibility rule.
        samples_per_m2, seed: surface sampling of every structure class.
        table: the class table (ids of the mesh's classes).
    """
    classes = face_classes(mesh)
    point_class = nearest_surface_class(scene, classes, xyz_m)
    structure = np.array([i for n, i in table.ids.items() if n not in ("none", "seafloor")])
    samples = surface_samples(mesh, structure, samples_per_m2, seed)
    seen = samples[visible(samples)] if len(samples) else samples
    sample_class = nearest_surface_class(scene, classes, seen)
    fused = np.asarray(map_table.column("source").to_pylist(), dtype=object) == "fused"
    distance = {
        "standard": nearest_distance(seen, xyz_m[fused], tolerance_m),
        "semantic": nearest_distance(seen, xyz_m, tolerance_m),
    }
    voxels = np.floor(map_xyz(map_table, "semantic") / voxel_size_m).astype(np.int64)
    return {
        "tolerance_m": tolerance_m,
        "voxel_size_m": voxel_size_m,
        "classes": class_table(
            point_class, error_m, fused, voxels, sample_class, distance, tolerance_m, table
        ),
        "assigned_classes": assigned_class_errors(map_table, error_m),
    }
