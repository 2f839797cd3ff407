"""Which ping pairs become submap frames, and where each sits relative to its keyframe.

Every keyframe owns the posed ping pairs recorded after it and before the next
keyframe (the last keyframe: to the end of the navigation stream). With stride k it
maps the k-th, 2k-th, ... of them. Each frame carries its dead-reckoning pose relative
to its keyframe, T_kf_frame = T_world_kf(DR)^-1 T_world_frame(DR): short-term dead
reckoning is accurate (DVL + IMU over 1-2 m), so this is the part of the pose that
the submap keeps, while the keyframe itself is placed by SLAM (McConnell et al.,
arXiv 2412.03760, Sec. III; our paper's Eq. 4 with T_world_frame = T_world_kf T_kf_frame).
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from sonarmap.schemas.keyframes import GT_POSE_COLUMNS, POSE_COLUMNS
from sonarmap.schemas.submaps import REL_POSE_COLUMNS, SUBMAP_FRAMES_SCHEMA
from sonarmap.stages.kernels.geometry import pose_from_se3
from sonarmap.stages.kernels.poses import pose_matrix

__all__ = ["relative_poses", "submap_frame_rows"]


def relative_poses(T_world_kf: np.ndarray, T_world_frame: np.ndarray) -> np.ndarray:
    """(n, 6) x, y, z, roll, pitch, yaw of T_kf_frame = T_world_kf^-1 T_world_frame."""
    T = np.linalg.inv(T_world_kf) @ T_world_frame
    return pose_from_se3(T)


def submap_frame_rows(
    keyframe_ping_index: np.ndarray,
    pair_h_index: np.ndarray,
    pair_v_index: np.ndarray,
    h_t_ns: np.ndarray,
    v_t_ns: np.ndarray,
    pose: np.ndarray,
    gt_pose: np.ndarray | None,
    stride: int,
) -> pa.Table:
    """The submap frames of a mission (`SUBMAP_FRAMES_SCHEMA`).

    Args:
        keyframe_ping_index: (k,) horizontal ping index of each keyframe, ascending
            (keyframes.parquet `ping_index_horizontal`, in keyframe-id order).
        pair_h_index, pair_v_index: (p,) ping indices of every posed pair, ascending.
        h_t_ns, v_t_ns: every horizontal / vertical ping time [ns].
        pose: (p, 6) dead-reckoning pose of each posed pair.
        gt_pose: (p, 6) true pose of each posed pair, or None.
        stride: keep every stride-th pair after each keyframe (0: none).

    Returns:
        One row per submap frame, frame ids 0.. in time order.
    """
    kf_ping = np.asarray(keyframe_ping_index, np.int64)
    h_idx = np.asarray(pair_h_index, np.int64)
    owner = np.searchsorted(kf_ping, h_idx, side="right") - 1
    between = (owner >= 0) & ~np.isin(h_idx, kf_ping)
    if stride <= 0 or kf_ping.size == 0:
        between[:] = False
    rows = np.flatnonzero(between)
    owner = owner[rows]
    # Position of each pair after its keyframe (1, 2, ...), counting every pair between.
    first_of_owner = np.searchsorted(owner, owner, side="left")
    position = np.arange(rows.size) - first_of_owner + 1
    keep = position % max(stride, 1) == 0
    rows, owner = rows[keep], owner[keep]
    kf_pair = np.searchsorted(h_idx, kf_ping[owner])
    rel = relative_poses(pose_matrix(pose[kf_pair]), pose_matrix(pose[rows]))
    n = rows.size
    cols: dict[str, object] = {
        "frame_id": np.arange(n, dtype=np.int64),
        "keyframe_id": owner.astype(np.int64),
        "t_ns": np.asarray(h_t_ns, np.int64)[h_idx[rows]],
        "t_vertical_ns": np.asarray(v_t_ns, np.int64)[np.asarray(pair_v_index, np.int64)[rows]],
        "ping_index_horizontal": h_idx[rows],
        "ping_index_vertical": np.asarray(pair_v_index, np.int64)[rows],
    }
    for c, name in enumerate(REL_POSE_COLUMNS):
        cols[name] = rel[:, c]
    for c, name in enumerate(POSE_COLUMNS):
        cols[name] = np.asarray(pose, np.float64)[rows, c]
    for c, name in enumerate(GT_POSE_COLUMNS):
        cols[name] = (
            pa.nulls(n, pa.float64())
            if gt_pose is None
            else pa.array(np.asarray(gt_pose, np.float64)[rows, c], pa.float64())
        )
    return pa.table(cols, schema=SUBMAP_FRAMES_SCHEMA)
