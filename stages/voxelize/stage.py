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

Inferred points of the classes in `evidence_classes` that the fused points of their own
world column contradict (`sonarmap.stages.voxelize.evidence`: the column holds enough fused
points and none near the predicted height) are dropped from the semantic map; this
catches an object given the wrong class (a truss called seawall receives wall heights).

Dense submaps (stage `submaps`, `keyframes.submap_stride` > 0): the points of the frames
between keyframes join both maps, registered through their keyframe's SLAM pose and
their dead-reckoning pose relative to it, T_world_kf T_kf_frame T_base_sonar; their
`frame_id` column tells them from the keyframes' own points (-1).

Outputs: `map` (`sonarmap.schemas.map.MAP_SCHEMA`), `voxels` (`VOXELS_SCHEMA`), `summary`
(voxel and point counts), and each map as a binary PLY coloured by height with vertex
properties class_id, source and keyframe_id (`sonarmap.stages.kernels.map_codes`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.schemas.map import MAP_NAMES, MAP_SCHEMA, NO_CLASS, VOXELS_SCHEMA
from sonarmap.schemas.sensors import Sensors
from sonarmap.schemas.submaps import KEYFRAME_FRAME_ID
from sonarmap.stages.kernels.colormaps import VIRIDIS_RGB8
from sonarmap.stages.kernels.map_codes import class_ids, source_ids
from sonarmap.stages.kernels.ply import encode_points_ply
from sonarmap.stages.kernels.poses import pose_matrices
from sonarmap.stages.kernels.registration import submap_world_points, world_points, xyz_columns
from sonarmap.stages.kernels.voxels import map_xyz, standard_rows, voxel_keys
from sonarmap.stages.voxelize import STAGE
from sonarmap.stages.voxelize.config import XYZ as _XYZ
from sonarmap.stages.voxelize.config import VoxelizeConfig
from sonarmap.stages.voxelize.evidence import contradicted_by_fused

__all__ = [
    "STAGE",
    "VoxelizeConfig",
    "build_map",
    "height_colours",
    "voxel_table",
]

logger = logging.getLogger(__name__)


def _class_lookup(fused: pa.Table, points: pa.Table) -> pa.Array:
    """Class name of each fused row: its object's class in infer.points, else none."""
    keys = ["keyframe_id", *_XYZ]
    fused_rows = points.filter(pc.equal(points.column("source"), "fused")).select(
        [*keys, "class_name"]
    )
    classes = fused_rows.group_by(keys).aggregate([("class_name", "min")])
    indexed = fused.select(keys).append_column("__row", pa.array(np.arange(fused.num_rows)))
    joined = indexed.join(classes, keys=keys, join_type="left outer")
    order = np.argsort(joined.column("__row").to_numpy(), kind="stable")
    names = pc.fill_null(joined.column("class_name_min"), NO_CLASS).combine_chunks()
    return names.take(pa.array(order)).cast(pa.string())


def _repeat(value: str, n: int) -> pa.Array:
    return pa.DictionaryArray.from_arrays(
        pa.array(np.zeros(n, np.int32)), pa.array([value], pa.string())
    ).cast(pa.string())


def build_map(
    points: pa.Table,
    fused: pa.Table,
    poses: pa.Table,
    T_base_sonar: np.ndarray,
    drop_above_surface: bool = True,
    submap_frames: pa.Table | None = None,
    submap_points: pa.Table | None = None,
    evidence: VoxelizeConfig | None = None,
) -> tuple[pa.Table, dict[str, int]]:
    """The world-frame map of fused and inferred points (Eq. 4).

    Args:
        points: infer.points (`sonarmap.schemas.points.POINTS_SCHEMA`), sonar frame.
        fused: fuse.fused (`sonarmap.schemas.fused.FUSED_SCHEMA`), sonar frame.
        poses: slam.poses (`sonarmap.schemas.slam.POSES_SCHEMA`), base_link in the world frame.
        T_base_sonar: (4, 4) horizontal sonar mounting.
        drop_above_surface: drop world points with z > 0.
        submap_frames, submap_points: stage `submaps` (`sonarmap.schemas.submaps`): points of the
            frames between keyframes, each registered through its keyframe's pose,
            T_world_kf T_kf_frame T_base_sonar (Eq. 4 extended).
        evidence: the `evidence_*` settings of this config (None: no evidence check).

    Returns:
        The map (`MAP_SCHEMA`, sorted by MAP_SORT_KEYS) and counts of the points
        dropped: {"above_surface": n, "without_pose": n, "contradicted": n}.
    """
    inferred = points.filter(pc.equal(points.column("source"), "inferred"))
    pose_ids, T_world_base = pose_matrices(poses)
    parts = []
    for table, source, names in (
        (fused, "fused", _class_lookup(fused, points)),
        (inferred, "inferred", inferred.column("class_name").combine_chunks()),
    ):
        kf = table.column("keyframe_id").to_numpy().astype(np.int64)
        world, posed = world_points(kf, xyz_columns(table), pose_ids, T_world_base, T_base_sonar)
        parts.append(
            (
                kf,
                np.full(kf.size, KEYFRAME_FRAME_ID, np.int64),
                world,
                posed,
                _repeat(source, kf.size),
                names,
            )
        )
    if submap_points is not None and submap_frames is not None and submap_points.num_rows:
        parts.append(
            submap_world_points(submap_frames, submap_points, pose_ids, T_world_base, T_base_sonar)
        )
    posed = np.concatenate([p[3] for p in parts])
    world = np.concatenate([p[2] for p in parts]).reshape(-1, 3)
    keyframe_parts, frame_parts = [p[0] for p in parts], [p[1] for p in parts]
    source_parts, class_parts = [p[4] for p in parts], [p[5] for p in parts]
    del parts  # the points live on in `world` only
    keep = world[:, 2] <= 0.0 if drop_above_surface else np.ones(len(world), bool)
    dropped = {"above_surface": int((~keep).sum()), "without_pose": int((~posed).sum())}
    if dropped["without_pose"]:
        logger.warning("%d points in keyframes without a pose dropped", dropped["without_pose"])
    rows = np.flatnonzero(posed)[keep]
    world = world[keep]
    source_names, source_code = _codes(pa.chunked_array(source_parts, pa.string()), rows)
    class_names, class_code = _codes(pa.chunked_array(class_parts, pa.string()), rows)
    del source_parts, class_parts
    supported = _supported(world, source_names, source_code, class_names, class_code, evidence)
    dropped["contradicted"] = int((~supported).sum())
    if not supported.all():
        rows, world, source_code, class_code = (
            rows[supported],
            world[supported],
            source_code[supported],
            class_code[supported],
        )
    kf = np.concatenate(keyframe_parts)[rows]
    frame = np.concatenate(frame_parts)[rows]
    del keyframe_parts, frame_parts, posed, rows
    # Sort before building the table (MAP_SORT_KEYS, codes in string order), so each
    # column exists once: a dense map is millions of rows.
    order = np.lexsort((world[:, 2], world[:, 1], world[:, 0], class_code, source_code, frame, kf))
    table = pa.table(
        {
            "keyframe_id": pa.array(kf[order], pa.int64()),
            "frame_id": pa.array(frame[order], pa.int64()),
            "x_m": pa.array(world[order, 0], pa.float64()),
            "y_m": pa.array(world[order, 1], pa.float64()),
            "z_m": pa.array(world[order, 2], pa.float64()),
            "source": _decode(source_names, source_code[order]),
            "class_name": _decode(class_names, class_code[order]),
        },
        schema=MAP_SCHEMA,
    )
    return table, dropped


def _supported(
    world: np.ndarray, source_names: pa.Array, source: np.ndarray, class_names: pa.Array,
    class_code: np.ndarray, evidence: VoxelizeConfig | None,
) -> np.ndarray:  # fmt: skip
    """False for the inferred points of `evidence.evidence_classes` that the fused
    points contradict (`sonarmap.stages.voxelize.evidence`); True for every other point."""
    out = np.ones(len(world), bool)
    if evidence is None or not evidence.evidence_classes:
        return out
    names = source_names.to_pylist()
    codes = {n: i for i, n in enumerate(names)}
    fused = source == codes.get("fused", -1)
    checked_classes = [
        i for i, c in enumerate(class_names.to_pylist()) if c in evidence.evidence_classes
    ]
    checked = (source == codes.get("inferred", -1)) & np.isin(class_code, checked_classes)
    rows = np.flatnonzero(checked)
    out[rows] = ~contradicted_by_fused(
        world,
        world[fused],
        cell_m=evidence.evidence_cell_m,
        height_tolerance_m=evidence.evidence_height_tolerance_m,
        min_fused=evidence.evidence_min_fused,
        rows=rows,
    )
    return out


def _codes(values: pa.ChunkedArray, rows: np.ndarray) -> tuple[pa.Array, np.ndarray]:
    """(sorted distinct strings, int32 code of each of `rows`): codes sort as the strings."""
    names = pc.unique(values).sort()
    return names, pc.index_in(values, value_set=names).to_numpy().astype(np.int32)[rows]


def _decode(names: pa.Array, codes: np.ndarray) -> pa.Array:
    return pa.DictionaryArray.from_arrays(pa.array(codes, pa.int32()), names).cast(pa.string())


def voxel_table(map_table: pa.Table, voxel_size_m: float) -> pa.Table:
    """Occupied voxels of both maps (`VOXELS_SCHEMA`, sorted by map, ix, iy, iz)."""
    parts: dict[str, list[Any]] = {k: [] for k in ("map", "ix", "iy", "iz", "n")}
    for name in MAP_NAMES:
        idx = np.floor(map_xyz(map_table, name) / voxel_size_m).astype(np.int64)
        _, first, counts = np.unique(voxel_keys(idx), return_index=True, return_counts=True)
        cells = idx[first].reshape(-1, 3)
        parts["map"].append(_repeat(name, len(cells)))
        for i, k in enumerate(("ix", "iy", "iz")):
            parts[k].append(cells[:, i])
        parts["n"].append(counts.astype(np.int64))
    return pa.table(
        {
            "map": pa.chunked_array(parts["map"], pa.string()),
            "ix": pa.array(np.concatenate(parts["ix"]), pa.int64()),
            "iy": pa.array(np.concatenate(parts["iy"]), pa.int64()),
            "iz": pa.array(np.concatenate(parts["iz"]), pa.int64()),
            "n_points": pa.array(np.concatenate(parts["n"]), pa.int64()),
        },
        schema=VOXELS_SCHEMA,
    )


def height_colours(z_m: np.ndarray, z_range_m: tuple[float, float] | None = None) -> np.ndarray:
    """(n, 3) uint8 viridis colours of heights z [m] over `z_range_m` (default: data range)."""
    n = len(VIRIDIS_RGB8)
    z = np.asarray(z_m, dtype=np.float64)
    lo, hi = z_range_m if z_range_m is not None else (z.min(initial=0.0), z.max(initial=0.0))
    t = np.clip((z - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.zeros_like(z)
    # matplotlib's colormap lookup (index floor(t N), t = 1 -> N - 1) on the fixed table
    return VIRIDIS_RGB8[np.minimum((t * n).astype(np.int64), n - 1)].reshape(-1, 3)


def _run(config: VoxelizeConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    T_base_sonar = Sensors.of(inputs["keyframes.sensors"]).horizontal.T_base_sonar
    table: ClassTable = inputs.get("config.classes", DEFAULT_TABLE)
    map_table, dropped = build_map(
        inputs["infer.points"],
        inputs["fuse.fused"],
        inputs["slam.poses"],
        T_base_sonar,
        config.drop_above_surface,
        inputs.get("submaps.frames"),
        inputs.get("submaps.points"),
        config,
    )
    voxels = voxel_table(map_table, config.voxel_size_m)
    z_all = map_table.column("z_m").to_numpy()
    z_range = (float(z_all.min(initial=0.0)), float(z_all.max(initial=0.0)))
    plys = {}
    for name in MAP_NAMES:
        # Column arrays, not an (n, 3) copy: the semantic map of a dense run is millions
        # of points, and this loop set voxelize's peak memory.
        t = map_table if name == "semantic" else standard_rows(map_table)
        x, y, z = (t.column(c).to_numpy() for c in _XYZ)
        plys[name] = encode_points_ply(
            (x, y, z),
            height_colours(z, z_range),
            f"sonarmap {name} map, world frame, coloured by height",
            {
                "class_id": class_ids(t.column("class_name"), table),
                "source": source_ids(t.column("source"), t.column("frame_id").to_numpy()),
                "keyframe_id": t.column("keyframe_id").to_numpy().astype(np.int32),
            },
        )
        del t, x, y, z
    summary = {
        "voxel_size_m": config.voxel_size_m,
        "voxels": {
            name: int(pc.sum(pc.equal(voxels.column("map"), name)).as_py() or 0)
            for name in MAP_NAMES
        },
        "points": {
            s: int(pc.sum(pc.equal(map_table.column("source"), s)).as_py() or 0)
            for s in ("fused", "inferred")
        },
        "dropped_points": dropped,
    }
    return {
        "map": map_table,
        "voxels": voxels,
        "summary": summary,
        "map_standard": plys["standard"],
        "map_semantic": plys["semantic"],
    }
