"""Stage `voxelize`: world-frame point maps and their 10 cm voxel counts (paper Sec. V,
Eq. 4, Table I).

Every 3D point of a keyframe, given in the horizontal sonar frame, is registered into
the world frame with that keyframe's SLAM pose (paper Eq. 4):
p_world = T_world_base(pose) @ T_base_sonar @ p_sonar, with the pose's rotation
R = Rz(yaw) Ry(pitch) Rx(roll). Points above the water surface (world z > 0) are
dropped, as the authors did (config `drop_above_surface`).

Two maps, as in the paper: the **standard** map is every fused point of `fuse.fused`
(orthogonal sonar fusion only, the benchmark); the **semantic** map adds the inferred
points of `infer.points` (`source == "inferred"`). Fused points are taken from
`fuse.fused` only, so none is counted twice; `infer.points`' fused rows only lend their
object's class name (matched on keyframe and exact sonar-frame coordinates, which the
infer stage copies unchanged).

Dense submaps (stage `submaps`, `keyframes.submap_stride` > 0): the points of the frames
between keyframes join both maps, registered through their keyframe's SLAM pose and
their dead-reckoning pose relative to it, T_world_kf T_kf_frame T_base_sonar; their
`frame_id` column tells them from the keyframes' own points (-1).

Outputs: `map` (`schemas.map.MAP_SCHEMA`), `voxels` (`VOXELS_SCHEMA`), `summary`
(voxel and point counts), and each map as a binary PLY coloured by height.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from pydantic import Field

from schemas.map import MAP_NAMES, MAP_SCHEMA, MAP_SORT_KEYS, NO_CLASS, VOXELS_SCHEMA
from schemas.submaps import KEYFRAME_FRAME_ID, REL_POSE_COLUMNS
from stages.base import Output, Stage, StageConfig
from stages.ply import encode_points_ply

__all__ = [
    "STAGE",
    "VoxelizeConfig",
    "build_map",
    "height_colours",
    "map_xyz",
    "pose_matrices",
    "rotation_rpy",
    "voxel_table",
    "world_points",
]

logger = logging.getLogger(__name__)

_XYZ = ("x_m", "y_m", "z_m")


class VoxelizeConfig(StageConfig):
    """Config section `voxelize`."""

    voxel_size_m: float = Field(
        0.1, ge=0.001, le=100.0, description="edge of a map voxel (paper: 10 cm)"
    )
    drop_above_surface: bool = Field(True, description="drop world points with z > 0")


def rotation_rpy(roll_rad: np.ndarray, pitch_rad: np.ndarray, yaw_rad: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations R = Rz(yaw) Ry(pitch) Rx(roll) (extrinsic x-y-z, ROS RPY)."""
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    cy, sy = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], axis=-1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], axis=-1),
            np.stack([-sp, cp * sr, cp * cr], axis=-1),
        ],
        axis=-2,
    )


def pose_matrices(poses: pa.Table, prefix: str = "") -> tuple[np.ndarray, np.ndarray]:
    """Keyframe poses as 4x4 transforms.

    Args:
        poses: table with keyframe_id and `{prefix}x_m ... {prefix}yaw_rad` [m, rad].
        prefix: column prefix ("gt_" for the ground-truth columns of keyframes.parquet).

    Returns:
        keyframe ids (k,) int64 sorted ascending, and (k, 4, 4) T_world_base.
    """
    kf = np.asarray(poses.column("keyframe_id").to_numpy(), dtype=np.int64)
    cols = {
        c: np.asarray(poses.column(prefix + c).to_numpy(zero_copy_only=False), np.float64)
        for c in ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
    }
    order = np.argsort(kf, kind="stable")
    T = np.tile(np.eye(4), (len(kf), 1, 1))
    T[:, :3, :3] = rotation_rpy(cols["roll_rad"], cols["pitch_rad"], cols["yaw_rad"])
    T[:, :3, 3] = np.stack([cols["x_m"], cols["y_m"], cols["z_m"]], axis=1)
    return kf[order], T[order]


def world_points(
    keyframe_id: np.ndarray,
    xyz_sonar_m: np.ndarray,
    pose_ids: np.ndarray,
    T_world_base: np.ndarray,
    T_base_sonar: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Paper Eq. 4: register sonar-frame points into the world frame.

    Args:
        keyframe_id: (n,) int64 keyframe of each point.
        xyz_sonar_m: (n, 3) points in the horizontal sonar frame [m].
        pose_ids: (k,) int64 sorted keyframe ids with a pose.
        T_world_base: (k, 4, 4) vehicle poses in the world frame.
        T_base_sonar: (4, 4) sonar mounting in base_link.

    Returns:
        (m, 3) world points [m] and the (n,) bool mask of points whose keyframe has a
        pose (the rows kept, in order).
    """
    kf = np.asarray(keyframe_id, dtype=np.int64)
    if len(pose_ids) == 0:
        return np.empty((0, 3)), np.zeros(len(kf), dtype=bool)
    idx = np.clip(np.searchsorted(pose_ids, kf), 0, len(pose_ids) - 1)
    posed = pose_ids[idx] == kf
    T = T_world_base[idx[posed]] @ np.asarray(T_base_sonar, dtype=np.float64)
    p = np.asarray(xyz_sonar_m, dtype=np.float64)[posed]
    world = np.einsum("nij,nj->ni", T[:, :3, :3], p) + T[:, :3, 3]
    return world, posed


def _class_lookup(fused: pa.Table, points: pa.Table) -> np.ndarray:
    """(n_fused,) class name of each fused row: its object's class in infer.points, else none."""
    keys = ["keyframe_id", *_XYZ]
    fused_rows = points.filter(pc.equal(points.column("source"), "fused")).select(
        [*keys, "class_name"]
    )
    classes = fused_rows.group_by(keys).aggregate([("class_name", "min")])
    indexed = fused.select(keys).append_column("__row", pa.array(np.arange(fused.num_rows)))
    joined = indexed.join(classes, keys=keys, join_type="left outer")
    out = np.full(fused.num_rows, NO_CLASS, dtype=object)
    rows = joined.column("__row").to_numpy()
    names = joined.column("class_name_min").to_pylist()
    out[rows] = [NO_CLASS if n is None else n for n in names]
    return out


def build_map(
    points: pa.Table,
    fused: pa.Table,
    poses: pa.Table,
    T_base_sonar: np.ndarray,
    drop_above_surface: bool = True,
    submap_frames: pa.Table | None = None,
    submap_points: pa.Table | None = None,
) -> tuple[pa.Table, dict[str, int]]:
    """The world-frame map of fused and inferred points (Eq. 4).

    Args:
        points: infer.points (`schemas.points.POINTS_SCHEMA`), sonar frame.
        fused: fuse.fused (`schemas.fused.FUSED_SCHEMA`), sonar frame.
        poses: slam.poses (`schemas.slam.POSES_SCHEMA`), base_link in the world frame.
        T_base_sonar: (4, 4) horizontal sonar mounting.
        drop_above_surface: drop world points with z > 0.
        submap_frames, submap_points: stage `submaps` (`schemas.submaps`): points of the
            frames between keyframes, each registered through its keyframe's pose,
            T_world_kf T_kf_frame T_base_sonar (Eq. 4 extended).

    Returns:
        The map (`MAP_SCHEMA`, sorted by MAP_SORT_KEYS) and counts of the points
        dropped: {"above_surface": n, "without_pose": n}.
    """
    inferred = points.filter(pc.equal(points.column("source"), "inferred"))
    kf = np.concatenate(
        [fused.column("keyframe_id").to_numpy(), inferred.column("keyframe_id").to_numpy()]
    ).astype(np.int64)
    xyz = np.concatenate(
        [
            np.stack([fused.column(c).to_numpy() for c in _XYZ], axis=1).reshape(-1, 3),
            np.stack([inferred.column(c).to_numpy() for c in _XYZ], axis=1).reshape(-1, 3),
        ]
    )
    source = np.array(["fused"] * fused.num_rows + ["inferred"] * inferred.num_rows, dtype=object)
    class_name = np.concatenate(
        [
            _class_lookup(fused, points),
            np.asarray(inferred.column("class_name").to_pylist(), object),
        ]
    )
    pose_ids, T_world_base = pose_matrices(poses)
    world, posed = world_points(kf, xyz, pose_ids, T_world_base, T_base_sonar)
    frame_id = np.full(kf.size, KEYFRAME_FRAME_ID, np.int64)
    if submap_points is not None and submap_frames is not None and submap_points.num_rows:
        sub = _submap_world_points(
            submap_frames, submap_points, pose_ids, T_world_base, T_base_sonar
        )
        world = np.concatenate([world, sub["world"]])
        posed = np.concatenate([posed, sub["posed"]])
        kf = np.concatenate([kf, sub["keyframe_id"]])
        frame_id = np.concatenate([frame_id, sub["frame_id"]])
        source = np.concatenate([source, sub["source"]])
        class_name = np.concatenate([class_name, sub["class_name"]])
    keep = world[:, 2] <= 0.0 if drop_above_surface else np.ones(len(world), bool)
    dropped = {"above_surface": int((~keep).sum()), "without_pose": int((~posed).sum())}
    if dropped["without_pose"]:
        logger.warning("%d points in keyframes without a pose dropped", dropped["without_pose"])
    table = pa.table(
        {
            "keyframe_id": pa.array(kf[posed][keep], pa.int64()),
            "frame_id": pa.array(frame_id[posed][keep], pa.int64()),
            "x_m": pa.array(world[keep, 0], pa.float64()),
            "y_m": pa.array(world[keep, 1], pa.float64()),
            "z_m": pa.array(world[keep, 2], pa.float64()),
            "source": pa.array(source[posed][keep], pa.string()),
            "class_name": pa.array(class_name[posed][keep], pa.string()),
        },
        schema=MAP_SCHEMA,
    )
    return table.sort_by([(k, "ascending") for k in MAP_SORT_KEYS]), dropped


def _submap_world_points(
    frames: pa.Table,
    points: pa.Table,
    pose_ids: np.ndarray,
    T_world_base: np.ndarray,
    T_base_sonar: np.ndarray,
) -> dict[str, np.ndarray]:
    """World points of the submap frames: T_world_kf(SLAM) T_kf_frame(DR) T_base_sonar."""
    frame_ids = frames.column("frame_id").to_numpy()
    rel = np.stack([frames.column(c).to_numpy() for c in REL_POSE_COLUMNS], axis=1)
    T_kf_frame = np.tile(np.eye(4), (len(rel), 1, 1))
    T_kf_frame[:, :3, :3] = rotation_rpy(rel[:, 3], rel[:, 4], rel[:, 5])
    T_kf_frame[:, :3, 3] = rel[:, :3]
    fid = points.column("frame_id").to_numpy()
    row = np.searchsorted(frame_ids, fid)
    if len(frame_ids) == 0 or (frame_ids[np.minimum(row, len(frame_ids) - 1)] != fid).any():
        raise ValueError("voxelize: submap points reference frames not in submap_frames")
    kf = frames.column("keyframe_id").to_numpy()[row]
    xyz = np.stack([points.column(c).to_numpy() for c in _XYZ], axis=1).reshape(-1, 3)
    # points in the keyframe's base_link: T_kf_frame T_base_sonar p; then Eq. 4 as for keyframes
    T = T_kf_frame[row] @ np.asarray(T_base_sonar, np.float64)
    in_kf_base = np.einsum("nij,nj->ni", T[:, :3, :3], xyz) + T[:, :3, 3]
    world, posed = world_points(kf, in_kf_base, pose_ids, T_world_base, np.eye(4))
    return {
        "world": world,  # rows of `posed` only, as world_points gives them
        "posed": posed,
        "keyframe_id": kf.astype(np.int64),
        "frame_id": fid.astype(np.int64),
        "source": np.asarray(points.column("source").to_pylist(), object),
        "class_name": np.asarray(points.column("class_name").to_pylist(), object),
    }


def map_xyz(map_table: pa.Table, name: str) -> np.ndarray:
    """(n, 3) world points [m] of one map ("standard": fused rows, "semantic": all)."""
    if name not in MAP_NAMES:
        raise ValueError(f"unknown map {name!r}; expected one of {MAP_NAMES}")
    t = map_table
    if name == "standard":
        t = t.filter(pc.equal(t.column("source"), "fused"))
    return np.stack([t.column(c).to_numpy() for c in _XYZ], axis=1).reshape(-1, 3)


def voxel_table(map_table: pa.Table, voxel_size_m: float) -> pa.Table:
    """Occupied voxels of both maps (`VOXELS_SCHEMA`, sorted by map, ix, iy, iz)."""
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("map", "ix", "iy", "iz", "n")}
    for name in MAP_NAMES:
        idx = np.floor(map_xyz(map_table, name) / voxel_size_m).astype(np.int64)
        cells, counts = np.unique(idx, axis=0, return_counts=True)
        cells = cells.reshape(-1, 3)
        parts["map"].append(np.full(len(cells), name, dtype=object))
        for i, k in enumerate(("ix", "iy", "iz")):
            parts[k].append(cells[:, i])
        parts["n"].append(counts.astype(np.int64))
    cols = {k: np.concatenate(v) for k, v in parts.items()}
    return pa.table(
        {
            "map": pa.array(cols["map"], pa.string()),
            "ix": pa.array(cols["ix"], pa.int64()),
            "iy": pa.array(cols["iy"], pa.int64()),
            "iz": pa.array(cols["iz"], pa.int64()),
            "n_points": pa.array(cols["n"], pa.int64()),
        },
        schema=VOXELS_SCHEMA,
    )


def height_colours(z_m: np.ndarray, z_range_m: tuple[float, float] | None = None) -> np.ndarray:
    """(n, 3) uint8 viridis colours of heights z [m] over `z_range_m` (default: data range)."""
    from matplotlib import colormaps

    z = np.asarray(z_m, dtype=np.float64)
    lo, hi = z_range_m if z_range_m is not None else (z.min(initial=0.0), z.max(initial=0.0))
    t = np.clip((z - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.zeros_like(z)
    rgba = colormaps["viridis"](t)
    return np.round(np.asarray(rgba)[:, :3] * 255.0).astype(np.uint8).reshape(-1, 3)


def _run(config: VoxelizeConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    sensors = inputs["keyframes.sensors"]
    T_base_sonar = np.asarray(sensors["horizontal"]["T_base_sonar"], dtype=np.float64)
    if T_base_sonar.shape != (4, 4):
        raise ValueError(f"sensors.horizontal.T_base_sonar: expected 4x4, got {T_base_sonar.shape}")
    map_table, dropped = build_map(
        inputs["infer.points"],
        inputs["fuse.fused"],
        inputs["slam.poses"],
        T_base_sonar,
        config.drop_above_surface,
        inputs.get("submaps.frames"),
        inputs.get("submaps.points"),
    )
    voxels = voxel_table(map_table, config.voxel_size_m)
    names = voxels.column("map").to_numpy(zero_copy_only=False)
    semantic = map_xyz(map_table, "semantic")
    z_range = (float(semantic[:, 2].min(initial=0.0)), float(semantic[:, 2].max(initial=0.0)))
    source = map_table.column("source").to_numpy(zero_copy_only=False)
    plys = {
        name: encode_points_ply(
            map_xyz(map_table, name),
            height_colours(map_xyz(map_table, name)[:, 2], z_range),
            f"sonarmap {name} map, world frame, coloured by height",
        )
        for name in MAP_NAMES
    }
    summary = {
        "voxel_size_m": config.voxel_size_m,
        "voxels": {name: int((names == name).sum()) for name in MAP_NAMES},
        "points": {s: int((source == s).sum()) for s in ("fused", "inferred")},
        "dropped_points": dropped,
    }
    return {
        "map": map_table,
        "voxels": voxels,
        "summary": summary,
        "map_standard": plys["standard"],
        "map_semantic": plys["semantic"],
    }


STAGE = Stage(
    name="voxelize",
    # 2: map.parquet gains frame_id; submap frames join the maps
    version=2,
    config=VoxelizeConfig,
    inputs=(
        "infer.points",
        "fuse.fused",
        "slam.poses",
        "keyframes.sensors",
        "submaps.frames",
        "submaps.points",
    ),
    outputs=(
        Output("map", "parquet", "map.parquet", schema=MAP_SCHEMA),
        Output("voxels", "parquet", "voxels.parquet", schema=VOXELS_SCHEMA),
        Output("summary", "json", "summary.json"),
        Output("map_standard", "bytes", "map_standard.ply"),
        Output("map_semantic", "bytes", "map_semantic.ply"),
    ),
    run=_run,
    description="register points with SLAM poses (Eq. 4), standard and semantic maps, voxel counts",
)
