"""Registration of sonar-frame points into the world frame (paper Eq. 4), for keyframes
and for the submap frames anchored to them (stage `submaps`)."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from sonarmap.schemas.submaps import REL_POSE_COLUMNS
from sonarmap.stages.kernels.poses import pose_matrix

__all__ = [
    "submap_world_points",
    "transform_grouped",
    "world_points",
]

_XYZ = ("x_m", "y_m", "z_m")


def xyz_columns(table: pa.Table) -> np.ndarray:
    """(n, 3) x_m, y_m, z_m of a table."""
    return np.stack([table.column(c).to_numpy() for c in _XYZ], axis=1).reshape(-1, 3)


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
    T = T_world_base @ np.asarray(T_base_sonar, dtype=np.float64)
    p = np.asarray(xyz_sonar_m, dtype=np.float64).reshape(-1, 3)[posed]
    return transform_grouped(idx[posed], p, T), posed


def transform_grouped(group: np.ndarray, xyz: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(n, 3) points xyz[i] moved by T[group[i]] ((g, 4, 4) transforms).

    One matrix product per group (keyframe or frame), so memory stays at the points
    themselves: a per-point (n, 4, 4) gather is 128 B a point, 450 MB for a dense map.
    """
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    out = np.empty_like(xyz)
    if xyz.size == 0:
        return out
    group = np.asarray(group, dtype=np.int64)
    order = np.argsort(group, kind="stable")
    g = group[order]
    starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    for a, b in zip(starts, np.r_[starts[1:], g.size], strict=True):
        rows = order[a:b]
        Tg = T[g[a]]
        out[rows] = xyz[rows] @ Tg[:3, :3].T + Tg[:3, 3]
    return out


def submap_world_points(
    frames: pa.Table,
    points: pa.Table,
    pose_ids: np.ndarray,
    T_world_base: np.ndarray,
    T_base_sonar: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, pa.Array, pa.Array]:
    """Submap points in the world: T_world_kf(SLAM) T_kf_frame(DR) T_base_sonar p.

    Returns (keyframe_id, frame_id, world points of the posed rows, posed mask,
    source, class_name), as `build_map` concatenates them.
    """
    frame_ids = frames.column("frame_id").to_numpy()
    rel = np.stack([frames.column(c).to_numpy() for c in REL_POSE_COLUMNS], axis=1)
    T_kf_frame = pose_matrix(rel)
    frame_kf = frames.column("keyframe_id").to_numpy().astype(np.int64)
    fid = points.column("frame_id").to_numpy().astype(np.int64)
    row = np.searchsorted(frame_ids, fid)
    if len(frame_ids) == 0 or (frame_ids[np.minimum(row, len(frame_ids) - 1)] != fid).any():
        raise ValueError("voxelize: submap points reference frames not in submap_frames")
    kf = frame_kf[row]
    # each frame's pose: its keyframe's (SLAM) composed with the relative DR pose
    at = np.clip(np.searchsorted(pose_ids, frame_kf), 0, max(len(pose_ids) - 1, 0))
    frame_posed = (pose_ids[at] == frame_kf) if len(pose_ids) else np.zeros(len(frame_kf), bool)
    T_world_frame = np.tile(np.eye(4), (len(frame_kf), 1, 1))
    if len(pose_ids):
        T_world_frame = T_world_base[at] @ T_kf_frame @ np.asarray(T_base_sonar, np.float64)
    posed = frame_posed[row]
    xyz = xyz_columns(points)
    # Subsetting copies every point; a dense map is millions, and usually all are posed.
    world = (
        transform_grouped(row, xyz, T_world_frame)
        if posed.all()
        else transform_grouped(row[posed], xyz[posed], T_world_frame)
    )
    del xyz
    return (
        kf,
        fid,
        world,
        posed,
        points.column("source").combine_chunks(),
        points.column("class_name").combine_chunks(),
    )
