"""The run's results as Foxglove messages (`foxglove-sdk` schemas) and as a map MCAP.

Pure functions from stage artifacts (Arrow tables, frames, mesh) to a list of
`SceneMessage` (topic, message, log time [ns]); `sonarmap.stages.evaluate.foxglove_map` writes
them with the SDK's MCAP writer into evaluate's `map.mcap`. The live view
(`sonarmap.pipeline.live`) publishes the same messages over the Foxglove WebSocket protocol as
each stage completes.

Topics (frame `map` is the world frame of `sonarmap.schemas.map`; log times come from the data):

- `/map/standard`, `/map/semantic`: `foxglove.PointCloud`, little-endian packed fields
  x y z (float32 [m]), class_id and source (uint8, `sonarmap.stages.kernels.map_codes`),
  keyframe_id (int32), and error (float32 [m], distance to the ground-truth mesh)
  where there is one.
- `/tf`: `foxglove.FrameTransforms`, map -> base_link at each keyframe's SLAM pose.
- `/trajectory/slam`, `/trajectory/dead_reckoning`, `/trajectory/ground_truth`:
  `foxglove.PosesInFrame`, one message of every keyframe pose.
- `/objects`: `foxglove.SceneUpdate`, a cylinder and label per classified object.
- `/sonar/horizontal/fan`, `/sonar/vertical/fan`: `foxglove.RawImage` mono8, each
  keyframe's polar image drawn as its fan (sensor at the bottom centre, forward up).
- `/ground_truth/mesh`: `foxglove.SceneUpdate` with the scene mesh as a triangle list.
- `/live/fused`: `foxglove.PointCloud` of the fused points at dead-reckoning poses (the
  live view's early map, before SLAM).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.schemas.map import NO_CLASS
from sonarmap.schemas.submaps import KEYFRAME_FRAME_ID
from sonarmap.stages.kernels.geometry import quat_from_rpy
from sonarmap.stages.kernels.map_codes import class_ids, source_ids
from sonarmap.stages.kernels.ply import Mesh
from sonarmap.stages.kernels.poses import pose_matrices
from sonarmap.stages.kernels.registration import world_points

__all__ = [
    "FRAME_BASE",
    "FRAME_MAP",
    "TOPIC_SCHEMAS",
    "SceneMessage",
    "cloud_records",
    "foxglove_messages",
    "fused_messages",
    "map_messages",
    "mesh_messages",
    "object_messages",
    "preview_messages",
    "timestamp",
    "trajectory_messages",
]

FRAME_MAP = "map"
FRAME_BASE = "base_link"

TOPIC_SCHEMAS: dict[str, str] = {
    "/map/standard": "PointCloud",
    "/map/semantic": "PointCloud",
    "/live/fused": "PointCloud",
    "/map/preview": "PointCloud",
    "/trajectory/preview": "PosesInFrame",
    "/tf": "FrameTransforms",
    "/trajectory/slam": "PosesInFrame",
    "/trajectory/dead_reckoning": "PosesInFrame",
    "/trajectory/ground_truth": "PosesInFrame",
    "/objects": "SceneUpdate",
    "/sonar/horizontal/fan": "RawImage",
    "/sonar/vertical/fan": "RawImage",
    "/ground_truth/mesh": "SceneUpdate",
}
"""Every topic and its `foxglove.messages` class name (schema `foxglove.<name>`)."""

_CLASS_COLOURS: tuple[tuple[float, float, float], ...] = (
    (0.12, 0.47, 0.71),
    (1.00, 0.50, 0.05),
    (0.17, 0.63, 0.17),
    (0.84, 0.15, 0.16),
    (0.58, 0.40, 0.74),
    (0.55, 0.34, 0.29),
    (0.89, 0.47, 0.76),
    (0.50, 0.50, 0.50),
)


class SceneMessage(NamedTuple):
    """One message to log: topic (a key of TOPIC_SCHEMAS), SDK message, log time [ns]."""

    topic: str
    message: Any
    log_time_ns: int


def foxglove_messages() -> Any:
    """The `foxglove.messages` module."""
    # Imported on first use: the SDK loads a native module that most stages never need.
    import foxglove.messages

    return foxglove.messages


def timestamp(t_ns: int) -> Any:
    """`foxglove.Timestamp` of a time [ns]."""
    return foxglove_messages().Timestamp(int(t_ns) // 1_000_000_000, int(t_ns) % 1_000_000_000)


def _quaternions(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(n, 4) x y z w of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    return quat_from_rpy(np.stack([roll, pitch, yaw], axis=-1))


def cloud_records(
    table: pa.Table, error_m: np.ndarray | None = None, classes: ClassTable = DEFAULT_TABLE
) -> np.ndarray:
    """Packed point records of map rows (`sonarmap.schemas.map.MAP_SCHEMA`, errors optional)."""
    fields: list[tuple[str, str]] = [
        ("x", "<f4"),
        ("y", "<f4"),
        ("z", "<f4"),
        ("class_id", "u1"),
        ("source", "u1"),
        ("pad", "<u2"),
        ("keyframe_id", "<i4"),
    ]
    if error_m is not None:
        fields.append(("error", "<f4"))
    # zeros, not empty: the padding bytes go into the file
    rec = np.zeros(table.num_rows, dtype=np.dtype(fields))
    for c in ("x", "y", "z"):
        rec[c] = table.column(f"{c}_m").to_numpy()
    rec["class_id"] = class_ids(table.column("class_name"), classes)
    frame = (
        table.column("frame_id").to_numpy()
        if "frame_id" in table.column_names
        else np.full(table.num_rows, KEYFRAME_FRAME_ID)
    )
    rec["source"] = source_ids(table.column("source"), frame)
    rec["keyframe_id"] = table.column("keyframe_id").to_numpy()
    if error_m is not None:
        rec["error"] = error_m
    return rec


def _point_cloud(rec: np.ndarray, t_ns: int) -> Any:
    fm = foxglove_messages()
    kinds = {
        "<f4": fm.PackedElementFieldNumericType.Float32,
        "|u1": fm.PackedElementFieldNumericType.Uint8,
        "<i4": fm.PackedElementFieldNumericType.Int32,
    }
    layout: Mapping[str, Any] = rec.dtype.fields or {}
    fields = [
        fm.PackedElementField(name=n, offset=spec[1], type=kinds[spec[0].str])
        for n, spec in layout.items()
        if n != "pad"
    ]
    return fm.PointCloud(
        timestamp=timestamp(t_ns),
        frame_id=FRAME_MAP,
        pose=fm.Pose(
            position=fm.Vector3(x=0.0, y=0.0, z=0.0),
            orientation=fm.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
        ),
        point_stride=rec.dtype.itemsize,
        fields=fields,
        data=rec.tobytes(),
    )


def map_messages(
    map_table: pa.Table,
    t_ns: int,
    errors: pa.Table | None = None,
    classes: ClassTable = DEFAULT_TABLE,
) -> list[SceneMessage]:
    """The standard (fused rows) and semantic (all rows) maps as point clouds at t_ns.

    `errors` (`sonarmap.schemas.map.ERRORS_SCHEMA`, the map's rows in the same order) adds the
    error field; `classes` is the class table (the points' class ids).
    """
    err = None if errors is None else errors.column("error_m").to_numpy()
    rec = cloud_records(map_table, err, classes)
    fused = pc.equal(map_table.column("source"), "fused").to_numpy(zero_copy_only=False)
    return [
        SceneMessage("/map/standard", _point_cloud(rec[fused], t_ns), t_ns),
        SceneMessage("/map/semantic", _point_cloud(rec, t_ns), t_ns),
    ]


def _pose_list(xyz: np.ndarray, quat: np.ndarray) -> list[Any]:
    fm = foxglove_messages()
    return [
        fm.Pose(
            position=fm.Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
            orientation=fm.Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
        )
        for p, q in zip(xyz.tolist(), quat.tolist(), strict=True)
    ]


def _poses(table: pa.Table, prefix: str = "") -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) positions and (n, 4) quaternions of `{prefix}x_m ... {prefix}yaw_rad`."""
    col = {c: table.column(f"{prefix}{c}").to_numpy() for c in ("x_m", "y_m", "z_m")}
    rpy = [table.column(f"{prefix}{c}").to_numpy() for c in ("roll_rad", "pitch_rad", "yaw_rad")]
    return np.stack([col["x_m"], col["y_m"], col["z_m"]], axis=1), _quaternions(*rpy)


def trajectory_messages(keyframes: pa.Table, poses: pa.Table | None) -> list[SceneMessage]:
    """/tf at each keyframe's SLAM pose, and the SLAM, dead-reckoning and (where the
    keyframes carry it) ground-truth trajectories, stamped at the last keyframe."""
    fm = foxglove_messages()
    t_end = int(pc.max(keyframes.column("t_ns")).as_py() or 0)
    out: list[SceneMessage] = []
    sources: list[tuple[str, pa.Table, str]] = [
        ("/trajectory/dead_reckoning", keyframes, ""),
    ]
    gt = keyframes.column("gt_x_m")
    if keyframes.num_rows and gt.null_count == 0:
        sources.append(("/trajectory/ground_truth", keyframes, "gt_"))
    if poses is not None:
        poses = poses.sort_by("keyframe_id")
        sources.insert(0, ("/trajectory/slam", poses, ""))
        xyz, quat = _poses(poses)
        for t, p, q in zip(
            poses.column("t_ns").to_pylist(), xyz.tolist(), quat.tolist(), strict=True
        ):
            transform = fm.FrameTransform(
                timestamp=timestamp(t),
                parent_frame_id=FRAME_MAP,
                child_frame_id=FRAME_BASE,
                translation=fm.Vector3(x=p[0], y=p[1], z=p[2]),
                rotation=fm.Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]),
            )
            out.append(SceneMessage("/tf", fm.FrameTransforms(transforms=[transform]), int(t)))
    for topic, table, prefix in sources:
        xyz, quat = _poses(table, prefix)
        msg = fm.PosesInFrame(
            timestamp=timestamp(t_end), frame_id=FRAME_MAP, poses=_pose_list(xyz, quat)
        )
        out.append(SceneMessage(topic, msg, t_end))
    return out


def fused_messages(
    fused: pa.Table,
    keyframes: pa.Table,
    T_base_sonar: np.ndarray,
    topic: str = "/live/fused",
    t_ns: int | None = None,
) -> list[SceneMessage]:
    """fuse.fused registered at the dead-reckoning keyframe poses, one cloud at the
    last keyframe (the map as far as the run knows before SLAM), or at `t_ns`;
    `follow`'s preview gives its own keyframes and points, its topic and its time."""
    ids, T = pose_matrices(keyframes)
    kf = fused.column("keyframe_id").to_numpy().astype(np.int64)
    xyz = np.stack([fused.column(c).to_numpy() for c in ("x_m", "y_m", "z_m")], axis=1)
    world, posed = world_points(kf, xyz.reshape(-1, 3), ids, T, T_base_sonar)
    world = world.reshape(-1, 3)
    n = len(world)
    table = pa.table(
        {
            "keyframe_id": pa.array(kf[posed], pa.int64()),
            "x_m": world[:, 0],
            "y_m": world[:, 1],
            "z_m": world[:, 2],
            "source": pa.array(np.full(n, "fused", object), pa.string()),
            "class_name": pa.array(np.full(n, NO_CLASS, object), pa.string()),
        }
    )
    t_end = int(pc.max(keyframes.column("t_ns")).as_py() or 0) if t_ns is None else t_ns
    return [SceneMessage(topic, _point_cloud(cloud_records(table), t_end), t_end)]


def preview_messages(
    fused: pa.Table, keyframes: pa.Table, T_base_sonar: np.ndarray, t_ns: int
) -> list[SceneMessage]:
    """`follow`'s preview (keyframes mapped since the last full update, at their
    dead-reckoned poses): its points on /map/preview and its keyframes on
    /trajectory/preview, stamped `t_ns`; empty tables clear both."""
    fm = foxglove_messages()
    cloud = fused_messages(fused, keyframes, T_base_sonar, "/map/preview", t_ns)[0]
    xyz, quat = _poses(keyframes)
    poses = fm.PosesInFrame(
        timestamp=timestamp(t_ns), frame_id=FRAME_MAP, poses=_pose_list(xyz, quat)
    )
    return [
        SceneMessage("/map/preview", cloud.message, t_ns),
        SceneMessage("/trajectory/preview", poses, t_ns),
    ]


def _colour(class_id: int) -> Any:
    r, g, b = _CLASS_COLOURS[class_id % len(_CLASS_COLOURS)]
    return foxglove_messages().Color(r=r, g=g, b=b, a=0.8)


def object_messages(
    objects: pa.Table,
    poses: pa.Table,
    T_base_sonar: np.ndarray,
    classes: ClassTable = DEFAULT_TABLE,
) -> list[SceneMessage]:
    """Each classified object (classify.objects, horizontal sonar frame) as a 1 m
    cylinder of its footprint's size at its world position, coloured by class and
    labelled; one SceneUpdate at the last pose's time."""
    fm = foxglove_messages()
    ids, T = pose_matrices(poses)
    kf = objects.column("keyframe_id").to_numpy().astype(np.int64)
    xyz = np.stack(
        [objects.column("x_m").to_numpy(), objects.column("y_m").to_numpy(), np.zeros(len(kf))],
        axis=1,
    )
    world, posed = world_points(kf, xyz.reshape(-1, 3), ids, T, T_base_sonar)
    world = world.reshape(-1, 3)
    rows = objects.filter(pa.array(posed))
    size = np.maximum(
        (rows.column("x_max_m").to_numpy() - rows.column("x_min_m").to_numpy()),
        (rows.column("y_max_m").to_numpy() - rows.column("y_min_m").to_numpy()),
    )
    cid = class_ids(rows.column("class_name"), classes)
    t_end = int(pc.max(poses.column("t_ns")).as_py() or 0)
    identity = fm.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
    entities = []
    for oid, name, c, p, d in zip(
        rows.column("object_id").to_pylist(),
        rows.column("class_name").to_pylist(),
        cid.tolist(),
        world.tolist(),
        size.tolist(),
        strict=True,
    ):
        pose = fm.Pose(position=fm.Vector3(x=p[0], y=p[1], z=p[2]), orientation=identity)
        label = fm.Pose(position=fm.Vector3(x=p[0], y=p[1], z=p[2] + 0.8), orientation=identity)
        entities.append(
            fm.SceneEntity(
                timestamp=timestamp(t_end),
                frame_id=FRAME_MAP,
                id=f"object-{oid}",
                frame_locked=True,
                cylinders=[
                    fm.CylinderPrimitive(
                        pose=pose,
                        size=fm.Vector3(x=max(d, 0.1), y=max(d, 0.1), z=1.0),
                        bottom_scale=1.0,
                        top_scale=1.0,
                        color=_colour(c),
                    )
                ],
                texts=[
                    fm.TextPrimitive(
                        pose=label,
                        billboard=True,
                        font_size=12.0,
                        scale_invariant=True,
                        color=fm.Color(r=1.0, g=1.0, b=1.0, a=1.0),
                        text=name,
                    )
                ],
            )
        )
    return [SceneMessage("/objects", fm.SceneUpdate(entities=entities), t_end)]


def mesh_messages(mesh: Mesh, t_ns: int) -> list[SceneMessage]:
    """The ground-truth scene mesh as one grey triangle list in the map frame."""
    fm = foxglove_messages()
    # The SDK takes points as objects: one per vertex of the (small) scene mesh.
    points = [fm.Point3(x=v[0], y=v[1], z=v[2]) for v in mesh.vertices.tolist()]
    triangles = fm.TriangleListPrimitive(
        pose=fm.Pose(
            position=fm.Vector3(x=0.0, y=0.0, z=0.0),
            orientation=fm.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
        ),
        points=points,
        color=fm.Color(r=0.6, g=0.6, b=0.6, a=0.35),
        indices=mesh.triangles.reshape(-1).astype(np.int64).tolist(),
    )
    entity = fm.SceneEntity(
        timestamp=timestamp(t_ns), frame_id=FRAME_MAP, id="ground-truth", triangles=[triangles]
    )
    return [SceneMessage("/ground_truth/mesh", fm.SceneUpdate(entities=[entity]), t_ns)]
