"""Map quality against a ground-truth mesh and trajectory error (paper Sec. V metrics).

- Absolute error of a map point: unsigned distance to the nearest ground-truth surface
  (open3d `RaycastingScene.compute_distance`), as in the paper's Fig. 4.
- Precision: fraction of map points within `tolerance_m` of the surface.
- Completeness: fraction of ground-truth surface samples of the mapped object classes
  within `tolerance_m` of a map point. Which part of the surface the vehicle could have
  seen is not known exactly; samples are kept when they are below the water surface
  (z <= 0), on a near-vertical face (|n_z| <= 0.5: pile caps and undersides face
  neither sonar) and, from at least one keyframe, inside the horizontal sonar's field of
  view (range <= max range, |bearing| <= fan / 2, |elevation| <= aperture / 2) and not
  hidden behind any ground-truth surface (a ray cast from the sonar). Acoustic shadows
  are geometric only: a return too weak to detect still counts as visible.
- Trajectory: absolute trajectory error (RMSE of the horizontal position) after the
  least-squares SE(2) alignment of the estimate to the ground truth (Umeyama without
  scale, in the plane).
"""

from __future__ import annotations

import numpy as np

from sonarmap.stages.kernels.lazy import lazy
from sonarmap.stages.kernels.ply import Mesh

o3d = lazy("open3d")
spatial = lazy("scipy.spatial")

__all__ = [
    "ate_se2",
    "error_stats",
    "fraction_within",
    "mesh_distance",
    "nearest_distance",
    "raycasting_scene",
    "sampled_area_m2",
    "se2_alignment",
    "surface_samples",
    "visible_mask",
]


def raycasting_scene(mesh: Mesh) -> o3d.t.geometry.RaycastingScene:
    """An open3d raycasting scene of the mesh's triangles (float32)."""
    if len(mesh.triangles) == 0:
        raise ValueError("ground-truth mesh has no triangles")
    tm = o3d.t.geometry.TriangleMesh()
    tm.vertex.positions = o3d.core.Tensor(mesh.vertices.astype(np.float32))
    tm.triangle.indices = o3d.core.Tensor(mesh.triangles.astype(np.int32))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(tm)
    return scene


def mesh_distance(mesh: Mesh | o3d.t.geometry.RaycastingScene, points_m: np.ndarray) -> np.ndarray:
    """(n,) float64 unsigned distance [m] from (n, 3) world points to the mesh surface."""
    pts = np.asarray(points_m, dtype=np.float32).reshape(-1, 3)
    if len(pts) == 0:
        return np.empty(0)
    scene = raycasting_scene(mesh) if isinstance(mesh, Mesh) else mesh
    return scene.compute_distance(o3d.core.Tensor(pts), nthreads=0).numpy().astype(np.float64)


def error_stats(error_m: np.ndarray) -> dict[str, float | int | None]:
    """Mean, median, 90th and 95th percentile [m] and count of errors (None when empty)."""
    e = np.asarray(error_m, dtype=np.float64)
    if e.size == 0:
        return {"mean_m": None, "median_m": None, "p90_m": None, "p95_m": None, "n": 0}
    return {
        "mean_m": float(e.mean()),
        "median_m": float(np.median(e)),
        "p90_m": float(np.percentile(e, 90)),
        "p95_m": float(np.percentile(e, 95)),
        "n": int(e.size),
    }


def fraction_within(distance_m: np.ndarray, tolerance_m: float) -> float | None:
    """Fraction of distances <= tolerance (None when there are none)."""
    d = np.asarray(distance_m)
    return float(np.mean(d <= tolerance_m)) if d.size else None


def _sampled_faces(
    mesh: Mesh, class_ids: np.ndarray, max_abs_normal_z: float
) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], np.ndarray, np.ndarray] | None:
    """((a, b, c) corners, areas, which faces `surface_samples` draws from), or None."""
    tri = mesh.triangles
    cls = mesh.vertex_properties.get("class_id")
    if cls is None or len(tri) == 0:
        return None
    a, b, c = (mesh.vertices[tri[:, i]] for i in range(3))
    cross = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cross, axis=1)
    nz = np.abs(cross[:, 2]) / np.maximum(2.0 * area, 1e-12)
    keep = np.isin(cls[tri[:, 0]], class_ids) & (nz <= max_abs_normal_z) & (area > 0)
    return (a, b, c), area, keep


def sampled_area_m2(mesh: Mesh, class_ids: np.ndarray, max_abs_normal_z: float = 0.5) -> float:
    """The area `surface_samples` draws from [m2] (its count is this times the density)."""
    faces = _sampled_faces(mesh, class_ids, max_abs_normal_z)
    return 0.0 if faces is None else float(faces[1][faces[2]].sum())


def surface_samples(
    mesh: Mesh,
    class_ids: np.ndarray,
    samples_per_m2: float,
    seed: int,
    max_abs_normal_z: float = 0.5,
) -> np.ndarray:
    """Uniform random points on the faces of the given classes.

    A face's class is its first vertex's `class_id`; faces with |normal z| above
    `max_abs_normal_z` (caps, undersides) are left out. The number of samples is
    round(area * samples_per_m2); faces are drawn by area, points uniformly inside.

    Returns:
        (s, 3) float64 world points [m]; the same inputs give the same points.
    """
    faces = _sampled_faces(mesh, class_ids, max_abs_normal_z)
    if faces is None:
        return np.empty((0, 3))
    (a, b, c), area, keep = faces
    total = float(area[keep].sum())
    n = round(total * samples_per_m2)
    if n == 0:
        return np.empty((0, 3))
    rng = np.random.default_rng(seed)
    faces = np.flatnonzero(keep)[rng.choice(int(keep.sum()), size=n, p=area[keep] / total)]
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    return a[faces] + u[:, None] * (b[faces] - a[faces]) + v[:, None] * (c[faces] - a[faces])


class _PlanarCells:
    """Points bucketed in square xy cells, so that a keyframe tests only the points near
    it instead of every point (the per-keyframe test is the same; `visible_mask`)."""

    def __init__(self, points_m: np.ndarray, index: np.ndarray, cell_m: float) -> None:
        self.cell_m = float(cell_m)
        ij = np.floor(points_m[index, :2] / self.cell_m).astype(np.int64).reshape(-1, 2)
        self.lo = ij.min(axis=0) if len(ij) else np.zeros(2, np.int64)
        ij -= self.lo
        self.shape = (ij.max(axis=0) + 1) if len(ij) else np.ones(2, np.int64)
        cell = ij[:, 0] * self.shape[1] + ij[:, 1]
        order = np.argsort(cell, kind="stable")
        self.index = index[order]
        self.starts = np.searchsorted(cell[order], np.arange(int(np.prod(self.shape)) + 1))

    def within_box(self, centre_xy_m: np.ndarray, half_side_m: float) -> np.ndarray:
        """Indices of every point in the cells that meet the square (a superset of it)."""
        c = np.asarray(centre_xy_m, dtype=np.float64)
        lo = np.maximum(np.floor((c - half_side_m) / self.cell_m).astype(np.int64) - self.lo, 0)
        hi = np.minimum(
            np.floor((c + half_side_m) / self.cell_m).astype(np.int64) - self.lo, self.shape - 1
        )
        if (lo > hi).any():
            return np.zeros(0, np.int64)
        rows = np.arange(lo[0], hi[0] + 1) * self.shape[1]
        a, b = self.starts[rows + lo[1]], self.starts[rows + hi[1] + 1]
        return np.concatenate([self.index[x:y] for x, y in zip(a, b, strict=True)])


def visible_mask(
    points_m: np.ndarray,
    T_world_sonar: np.ndarray,
    max_range_m: float,
    half_fan_rad: float,
    half_aperture_rad: float,
    scene: o3d.t.geometry.RaycastingScene | None = None,
    occlusion_tolerance_m: float = 0.02,
    min_range_m: float = 0.0,
) -> np.ndarray:
    """(n,) bool: below the surface, inside the sonar's field of view of some keyframe and,
    with `scene`, not hidden behind another surface from that keyframe.

    Args:
        points_m: (n, 3) world points [m] (surface samples).
        T_world_sonar: (k, 4, 4) horizontal sonar poses, one per keyframe.
        max_range_m: sonar maximum range [m].
        half_fan_rad: half the horizontal field of view (bearing) [rad].
        half_aperture_rad: half the vertical aperture (elevation) [rad].
        scene: the ground-truth surfaces; a point counts as seen from a keyframe only
            if the ray from the sonar origin first hits a surface no nearer than its
            range minus `occlusion_tolerance_m` (back faces are hidden by front faces).
        occlusion_tolerance_m: slack for float32 ray casting [m].
        min_range_m: sonar minimum range [m] (nearer points are not imaged).
    """
    p = np.asarray(points_m, dtype=np.float32).reshape(-1, 3)
    below = p[:, 2] <= 0.0
    seen = np.zeros(len(p), dtype=bool)
    cos_fan, sin_aperture = np.cos(half_fan_rad), np.sin(half_aperture_rad)
    cells = _PlanarCells(p, np.flatnonzero(below), max_range_m / 2.0)
    # A little beyond the range, so float32 rounding never drops a point the exact test keeps.
    reach = max_range_m * (1.0 + 1e-5) + 1e-3
    for T in np.asarray(T_world_sonar, dtype=np.float32):
        todo = cells.within_box(T[:2, 3], reach)
        todo = todo[~seen[todo]]
        d = p[todo] - T[:3, 3]
        local = d @ T[:3, :3]
        r2_xy = local[:, 0] ** 2 + local[:, 1] ** 2
        r2 = r2_xy + local[:, 2] ** 2
        cand = (
            (r2 <= max_range_m**2)
            & (r2 > 0)
            & (r2 >= min_range_m**2)
            & (local[:, 0] >= cos_fan * np.sqrt(r2_xy))
            & (local[:, 2] ** 2 <= sin_aperture**2 * r2)
        )
        todo, d, r = todo[cand], d[cand], np.sqrt(r2[cand])
        if scene is not None and len(todo):
            rays = np.concatenate([np.broadcast_to(T[:3, 3], d.shape), d / r[:, None]], axis=1)
            hit = scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays)), nthreads=0)
            todo = todo[hit["t_hit"].numpy() >= r - occlusion_tolerance_m]
        seen[todo] = True
    return seen & below


def nearest_distance(query_m: np.ndarray, cloud_m: np.ndarray, upper_m: float) -> np.ndarray:
    """(n,) distance [m] from each query point to its nearest cloud point (inf beyond upper_m)."""
    q = np.asarray(query_m, dtype=np.float64).reshape(-1, 3)
    if len(cloud_m) == 0 or len(q) == 0:
        return np.full(len(q), np.inf)
    d, _ = spatial.cKDTree(np.asarray(cloud_m, dtype=np.float64)).query(
        q, distance_upper_bound=upper_m, workers=-1
    )
    return np.asarray(d, dtype=np.float64)


def se2_alignment(
    estimate_xy_m: np.ndarray, truth_xy_m: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares planar rigid transform taking estimate to truth (Umeyama 1991, no scale).

    Args:
        estimate_xy_m: (n, 2) estimated positions [m], n >= 1.
        truth_xy_m: (n, 2) true positions at the same times [m].

    Returns:
        (R (2, 2), t (2,)) minimising sum ||R e_i + t - g_i||^2.
    """
    e = np.asarray(estimate_xy_m, dtype=np.float64).reshape(-1, 2)
    g = np.asarray(truth_xy_m, dtype=np.float64).reshape(-1, 2)
    me, mg = e.mean(axis=0), g.mean(axis=0)
    cov = (g - mg).T @ (e - me)
    u, _, vt = np.linalg.svd(cov)
    s = np.diag([1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
    R = u @ s @ vt
    return R, mg - R @ me


def ate_se2(estimate_xy_m: np.ndarray, truth_xy_m: np.ndarray) -> float | None:
    """ATE RMSE [m] after the least-squares SE(2) alignment of estimate to truth.

    Args:
        estimate_xy_m: (n, 2) estimated positions [m].
        truth_xy_m: (n, 2) true positions at the same times [m].

    Returns:
        sqrt(mean ||R e_i + t - g_i||^2) with (R, t) = `se2_alignment`; None when n == 0.
    """
    e = np.asarray(estimate_xy_m, dtype=np.float64).reshape(-1, 2)
    g = np.asarray(truth_xy_m, dtype=np.float64).reshape(-1, 2)
    if len(e) == 0:
        return None
    R, t = se2_alignment(e, g)
    aligned = e @ R.T + t
    return float(np.sqrt(np.mean(np.sum((aligned - g) ** 2, axis=1))))
