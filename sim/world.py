"""Ground-truth world: scene primitives as triangle meshes in an open3d RaycastingScene."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.sim.meshes import primitive_mesh, seafloor_mesh
from sonarmap.sim.scene import Scene, SceneError

__all__ = ["ObjectInfo", "World"]


@dataclass(frozen=True)
class ObjectInfo:
    """One meshed object: id (index in `World.objects`), class, name and its AABB [m]."""

    object_id: int
    class_id: int
    class_name: str
    name: str
    bbox_min: tuple[float, float, float]
    bbox_max: tuple[float, float, float]


class World:
    """Triangle meshes of a scene in a `RaycastingScene`, keeping geometry -> object -> class.

    Object ids are the scene's expanded primitives in file order (0..n-1); the seafloor is
    the last object (class "seafloor"). `cast_threads`: open3d threads per ray cast (0: all
    cores; a worker process among others takes 1); hits do not depend on it. `table`: the
    class table (config section `classes`) giving each object's class its label id.
    """

    def __init__(
        self, scene: Scene, cast_threads: int = 0, table: ClassTable = DEFAULT_TABLE
    ) -> None:
        self.scene = scene
        self.table = table
        self.cast_threads = int(cast_threads)
        ids = table.ids
        meshes = [primitive_mesh(p, scene.seafloor_depth_m) for p in scene.primitives()]
        names = [p.name or f"{p.kind}_{i}" for i, p in enumerate(scene.primitives())]
        unknown = sorted({p.kind for p in scene.primitives()} - set(ids))
        if unknown:
            raise SceneError(
                f"scene {scene.name}: class {unknown[0]!r:.60} is not in the class table"
                f" (classes.table: {', '.join(ids)})"
            )
        classes = [ids[p.kind] for p in scene.primitives()]
        meshes.append(seafloor_mesh(scene.area_m, scene.seafloor_depth_m, scene.seafloor_margin_m))
        names.append("seafloor")
        classes.append(ids["seafloor"])
        self._meshes = meshes
        self._class_of_object = np.asarray(classes, dtype=np.int64)
        self.objects: list[ObjectInfo] = []
        self._rc = o3d.t.geometry.RaycastingScene()
        self._rc_obstacles = o3d.t.geometry.RaycastingScene()
        gids = []
        for oid, (v, t) in enumerate(meshes):
            tm = o3d.t.geometry.TriangleMesh()
            tm.vertex.positions = o3d.core.Tensor(v.astype(np.float32))  # type: ignore[call-overload]
            tm.triangle.indices = o3d.core.Tensor(t.astype(np.int32))  # type: ignore[call-overload]
            gids.append(self._rc.add_triangles(tm))
            if classes[oid] != ids["seafloor"]:
                self._rc_obstacles.add_triangles(tm)
            lo, hi = v.min(axis=0), v.max(axis=0)
            self.objects.append(
                ObjectInfo(
                    oid,
                    classes[oid],
                    table.name_of(classes[oid]),
                    names[oid],
                    (float(lo[0]), float(lo[1]), float(lo[2])),
                    (float(hi[0]), float(hi[1]), float(hi[2])),
                )
            )
        self._object_of_gid = np.full(max(gids) + 1, -1, dtype=np.int64)
        self._object_of_gid[np.asarray(gids)] = np.arange(len(gids))
        self._n_obstacles = len(meshes) - 1
        # Build the BVHs now, so later queries (possibly from threads) only read them.
        self.cast(np.zeros((1, 3)), np.array([[1.0, 0.0, 0.0]]))
        self.distance(np.zeros((1, 3)), include_seafloor=False)

    @property
    def class_of_object(self) -> np.ndarray:
        """(n_objects,) int64 class id of each object id."""
        return self._class_of_object.copy()

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> dict[str, np.ndarray]:
        """Cast rays, first hit each.

        Args:
            origins: (n, 3) ray origins, world frame [m].
            dirs: (n, 3) unit directions, world frame.

        Returns:
            t_hit (n,) float64 range [m] (inf on a miss), normal (n, 3) float64 unit triangle
            normal (0 on a miss), object_id (n,) int64 (-1 on a miss), class_id (n,) int64 (0).
        """
        rays = np.concatenate([origins, dirs], axis=1).astype(np.float32)
        ans = self._rc.cast_rays(o3d.core.Tensor(rays), nthreads=self.cast_threads)  # type: ignore[call-overload]
        t_hit = ans["t_hit"].numpy().astype(np.float64)
        gid = ans["geometry_ids"].numpy().astype(np.int64)
        hit = np.isfinite(t_hit)
        obj = np.full(len(t_hit), -1, dtype=np.int64)
        obj[hit] = self._object_of_gid[gid[hit]]
        cls = np.zeros(len(t_hit), dtype=np.int64)
        cls[hit] = self._class_of_object[obj[hit]]
        return {
            "t_hit": t_hit,
            "normal": ans["primitive_normals"].numpy().astype(np.float64),
            "object_id": obj,
            "class_id": cls,
        }

    def distance(self, points: np.ndarray, *, include_seafloor: bool = True) -> np.ndarray:
        """(n,) float64 unsigned distance [m] from (n, 3) world points to the surfaces."""
        rc = self._rc if include_seafloor else self._rc_obstacles
        if not include_seafloor and self._n_obstacles == 0:
            return np.full(len(points), np.inf)
        q = o3d.core.Tensor(np.asarray(points, dtype=np.float32).reshape(-1, 3))  # type: ignore[call-overload]
        return rc.compute_distance(q, nthreads=0).numpy().astype(np.float64)

    def mesh_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """All objects as one mesh: vertices (v, 3) f64, triangles (t, 3) i32,
        vertex_object_id (v,) int32, vertex_class_id (v,) uint8."""
        verts, tris, oids, base = [], [], [], 0
        for oid, (v, t) in enumerate(self._meshes):
            verts.append(v)
            tris.append(t + base)
            oids.append(np.full(len(v), oid, dtype=np.int32))
            base += len(v)
        oid_all = np.concatenate(oids)
        cls = self._class_of_object[oid_all].astype(np.uint8)
        return (
            np.concatenate(verts).astype(np.float64),
            np.concatenate(tris).astype(np.int32),
            oid_all,
            cls,
        )

    def to_ply_bytes(self) -> bytes:
        """Binary little-endian PLY: vertex x y z (float32), object_id (int32), class_id (uchar);
        faces as uchar-count int32 index lists."""
        v, t, oid, cls = self.mesh_arrays()
        vdt = np.dtype(
            [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("object_id", "<i4"), ("class_id", "u1")]
        )
        va = np.empty(len(v), dtype=vdt)
        va["x"], va["y"], va["z"] = v[:, 0], v[:, 1], v[:, 2]
        va["object_id"], va["class_id"] = oid, cls
        fdt = np.dtype([("n", "u1"), ("i", "<i4", (3,))])
        fa = np.empty(len(t), dtype=fdt)
        fa["n"], fa["i"] = 3, t
        header = (
            "ply\nformat binary_little_endian 1.0\ncomment sonarmap simulator ground truth\n"
            f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
            "property int object_id\nproperty uchar class_id\n"
            f"element face {len(t)}\nproperty list uchar int vertex_indices\nend_header\n"
        )
        return header.encode("ascii") + va.tobytes() + fa.tobytes()

    def surface_samples(
        self, spacing_m: float, classes: list[str] | list[int] | None = None
    ) -> np.ndarray:
        """Deterministic area-uniform points on the surfaces, about one per spacing_m^2.

        Args:
            spacing_m: mean point spacing [m].
            classes: class names or ids to keep (None = all, seafloor included).

        Returns:
            (n, 3) float64 world points [m].
        """
        v, t, _, cls = self.mesh_arrays()
        keep = np.ones(len(t), dtype=bool)
        if classes is not None:
            wanted = {self.table.ids[c] if isinstance(c, str) else int(c) for c in classes}
            keep = np.isin(cls[t[:, 0]], sorted(wanted))
        tri = v[t[keep]]
        if len(tri) == 0:
            return np.zeros((0, 3))
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        n_per = np.floor(area / spacing_m**2 + 0.5).astype(np.int64)
        n_per = np.maximum(n_per, (area > 0).astype(np.int64))
        idx = np.repeat(np.arange(len(tri)), n_per)
        rng = np.random.default_rng(0)
        u, w = rng.random(len(idx)), rng.random(len(idx))
        flip = u + w > 1
        u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
        a = tri[idx]
        return a[:, 0] + u[:, None] * (a[:, 1] - a[:, 0]) + w[:, None] * (a[:, 2] - a[:, 0])
