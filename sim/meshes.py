"""Triangle meshes (numpy vertices/triangles) of the scene primitives, world frame [m]."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from sonarmap.sim.scene import (
    BoatHull,
    CylindricalPiling,
    MeshObject,
    Primitive,
    RectangularPiling,
    SceneError,
    Seawall,
    Truss,
)
from sonarmap.stages.kernels.geometry import matrix_from_rpy

__all__ = ["Mesh", "beam_mesh", "box_mesh", "file_mesh", "primitive_mesh", "seafloor_mesh"]

Mesh = tuple[np.ndarray, np.ndarray]
"""(vertices (v, 3) float64, triangles (t, 3) int32)."""

SURFACE_TOP_M = 1.0
"""Top of objects that reach through the surface [m above z = 0]."""


def _top(height_m: float | None, floor_z: float) -> float:
    return SURFACE_TOP_M if height_m is None else floor_z + height_m


def _cylinder(cx: float, cy: float, r: float, z0: float, z1: float, n: int = 24) -> Mesh:
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    ring = np.stack([cx + r * np.cos(a), cy + r * np.sin(a)], axis=1)
    v = np.concatenate(
        [np.c_[ring, np.full(n, z0)], np.c_[ring, np.full(n, z1)], [[cx, cy, z0], [cx, cy, z1]]]
    )
    i = np.arange(n)
    j = (i + 1) % n
    side = np.concatenate([np.c_[i, j, n + j], np.c_[i, n + j, n + i]])
    caps = np.concatenate(
        [np.c_[np.full(n, 2 * n), j, i], np.c_[np.full(n, 2 * n + 1), n + i, n + j]]
    )
    return v, np.concatenate([side, caps]).astype(np.int32)


_BOX_T = np.array(
    [
        [0, 2, 1],
        [0, 3, 2],
        [4, 5, 6],
        [4, 6, 7],
        [0, 1, 5],
        [0, 5, 4],
        [1, 2, 6],
        [1, 6, 5],
        [2, 3, 7],
        [2, 7, 6],
        [3, 0, 4],
        [3, 4, 7],
    ],
    dtype=np.int32,
)


def box_mesh(center: np.ndarray, axes: np.ndarray, half: np.ndarray) -> Mesh:
    """Oriented box: centre (3,), unit axes as rows (3, 3), half extents (3,)."""
    s = np.array(
        [
            [-1, -1, -1],
            [1, -1, -1],
            [1, 1, -1],
            [-1, 1, -1],
            [-1, -1, 1],
            [1, -1, 1],
            [1, 1, 1],
            [-1, 1, 1],
        ],
        dtype=float,
    )
    v = center[None] + (s * half[None]) @ axes
    return v, _BOX_T.copy()


def beam_mesh(p0: np.ndarray, p1: np.ndarray, width_m: float) -> Mesh:
    """Square-section beam of side `width_m` from p0 to p1 (3,)."""
    u = (p1 - p0) / np.linalg.norm(p1 - p0)
    ref = np.array([0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    v = np.cross(ref, u)
    v /= np.linalg.norm(v)
    w = np.cross(u, v)
    half = np.array([np.linalg.norm(p1 - p0) / 2, width_m / 2, width_m / 2])
    return box_mesh((p0 + p1) / 2, np.stack([u, v, w]), half)


def _rect_piling(o: RectangularPiling, floor_z: float) -> Mesh:
    z1 = _top(o.height_m, floor_z)
    c, s = np.cos(np.deg2rad(o.yaw_deg)), np.sin(np.deg2rad(o.yaw_deg))
    axes = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    center = np.array([o.position_m[0], o.position_m[1], (floor_z + z1) / 2])
    return box_mesh(center, axes, np.array([o.width_m / 2, o.depth_m / 2, (z1 - floor_z) / 2]))


def _seawall(o: Seawall, floor_z: float) -> Mesh:
    z1 = _top(o.height_m, floor_z)
    verts, tris, base = [], [], 0
    poly = np.asarray(o.polyline_m, dtype=float)
    for a, b in itertools.pairwise(poly):
        length = float(np.linalg.norm(b - a))
        n_s = max(int(np.ceil(length / (o.corrugation_period_m / 8))), 1) + 1
        s = np.linspace(0.0, length, n_s)
        t = (b - a) / length
        nrm = np.array([-t[1], t[0]])
        off = 0.5 * o.corrugation_depth_m * np.sin(2 * np.pi * s / o.corrugation_period_m)
        xy = a[None] + s[:, None] * t[None] + off[:, None] * nrm[None]
        verts.append(
            np.concatenate([np.c_[xy, np.full(n_s, floor_z)], np.c_[xy, np.full(n_s, z1)]])
        )
        i = np.arange(n_s - 1)
        tris.append(
            base + np.concatenate([np.c_[i, i + 1, n_s + i + 1], np.c_[i, n_s + i + 1, n_s + i]])
        )
        base += 2 * n_s
    return np.concatenate(verts), np.concatenate(tris).astype(np.int32)


def _hull(o: BoatHull, n_u: int = 10, n_v: int = 32) -> Mesh:
    u = np.linspace(0.0, np.pi / 2, n_u)[1:]
    v = np.linspace(0.0, 2 * np.pi, n_v, endpoint=False)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    x = 0.5 * o.length_m * np.sin(uu) * np.cos(vv)
    y = 0.5 * o.beam_m * np.sin(uu) * np.sin(vv)
    z = -o.draft_m * np.cos(uu)
    rings = np.stack([x, y, z], axis=-1)
    top = rings[-1].copy()
    top[:, 2] = o.freeboard_m
    rings = np.concatenate([rings, top[None]], axis=0)
    nr = rings.shape[0]
    pts = np.concatenate(
        [rings.reshape(-1, 3), [[0.0, 0.0, -o.draft_m], [0.0, 0.0, o.freeboard_m]]]
    )
    k = np.arange(nr - 1)[:, None] * n_v
    j = np.arange(n_v)[None]
    jn = (j + 1) % n_v
    a, b, c, d = k + j, k + jn, k + n_v + jn, k + n_v + j
    side = np.concatenate(
        [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)]
    )
    jj = np.arange(n_v)
    bottom = np.c_[np.full(n_v, nr * n_v), (jj + 1) % n_v, jj]
    deck = np.c_[np.full(n_v, nr * n_v + 1), (nr - 1) * n_v + jj, (nr - 1) * n_v + (jj + 1) % n_v]
    c_, s_ = np.cos(np.deg2rad(o.yaw_deg)), np.sin(np.deg2rad(o.yaw_deg))
    rot = np.array([[c_, -s_, 0.0], [s_, c_, 0.0], [0.0, 0.0, 1.0]])
    pts = pts @ rot.T + np.array([o.position_m[0], o.position_m[1], 0.0])
    return pts, np.concatenate([side, bottom, deck]).astype(np.int32)


def _truss(o: Truss) -> Mesh:
    a, b = np.asarray(o.start_m, float), np.asarray(o.end_m, float)
    s = np.linspace(0.0, 1.0, o.bays + 1)
    xy = a[None] + s[:, None] * (b - a)[None]
    top = np.c_[xy, np.full(len(s), o.top_z_m)]
    bot = np.c_[xy, np.full(len(s), o.bottom_z_m)]
    members = [(top[0], top[-1]), (bot[0], bot[-1])]
    for i in range(o.bays + 1):
        members.append((bot[i], top[i]))
    for i in range(o.bays):
        members.append((bot[i], top[i + 1]) if i % 2 == 0 else (top[i], bot[i + 1]))
    return _merge([beam_mesh(p, q, o.member_width_m) for p, q in members])


def _merge(meshes: list[Mesh]) -> Mesh:
    verts, tris, base = [], [], 0
    for v, t in meshes:
        verts.append(v)
        tris.append(t + base)
        base += len(v)
    return np.concatenate(verts), np.concatenate(tris).astype(np.int32)


def file_mesh(obj: MeshObject, floor_z: float) -> Mesh:
    """A mesh file's triangles, scaled, turned about z and placed (`MeshObject`)."""
    import open3d as o3d

    # Open3D prints its reader's complaints on stdout, in colour; the one-line refusal
    # below says what is wrong with the file.
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh = o3d.io.read_triangle_mesh(Path(obj.file))
    v = np.asarray(mesh.vertices, np.float64)
    t = np.asarray(mesh.triangles, np.int32)
    if len(t) == 0 or not np.isfinite(v).all():
        raise SceneError(f"mesh {obj.file}: no triangles, or not a mesh open3d can read")
    v = (v * obj.scale) @ matrix_from_rpy([0.0, 0.0, np.deg2rad(obj.yaw_deg)]).T
    bottom = floor_z if obj.z_m is None else obj.z_m
    v += np.array([obj.position_m[0], obj.position_m[1], bottom - v[:, 2].min()])
    return v, t


def primitive_mesh(obj: Primitive, seafloor_depth_m: float) -> Mesh:
    """World-frame triangle mesh of one scene primitive."""
    floor_z = -seafloor_depth_m
    if isinstance(obj, MeshObject):
        return file_mesh(obj, floor_z)
    if isinstance(obj, CylindricalPiling):
        return _cylinder(
            obj.position_m[0], obj.position_m[1], obj.radius_m, floor_z, _top(obj.height_m, floor_z)
        )
    if isinstance(obj, RectangularPiling):
        return _rect_piling(obj, floor_z)
    if isinstance(obj, Seawall):
        return _seawall(obj, floor_z)
    if isinstance(obj, BoatHull):
        return _hull(obj)
    return _truss(obj)


def seafloor_mesh(
    area_m: tuple[float, float, float, float], depth_m: float, margin_m: float, cell_m: float = 10.0
) -> Mesh:
    """Flat seafloor z = -depth_m over the area plus margin, as a grid of triangles."""
    x0, x1, y0, y1 = area_m
    xs = np.arange(x0 - margin_m, x1 + margin_m + cell_m, cell_m)
    ys = np.arange(y0 - margin_m, y1 + margin_m + cell_m, cell_m)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    v = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, -depth_m)], axis=1)
    nx, ny = len(xs), len(ys)
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), indexing="ij")
    a = (i * ny + j).ravel()
    b, c, d = a + ny, a + ny + 1, a + 1
    t = np.concatenate([np.c_[a, b, c], np.c_[a, c, d]]).astype(np.int32)
    return v, t
