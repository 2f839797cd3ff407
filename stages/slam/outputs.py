"""Output files of the `slam` stage: poses and factors tables, TUM trajectory, plot points."""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.schemas.figures import PLOT_POINTS_SCHEMA
from sonarmap.schemas.slam import COVARIANCE_COLUMNS, FACTORS_SCHEMA, POSES_SCHEMA
from sonarmap.stages.kernels.geometry import quat_from_rpy
from sonarmap.stages.slam.scan_matching import transform_points

__all__ = ["factors_table", "plot_points", "poses_table", "tum_text"]

_TRIU = np.triu_indices(3)


def poses_table(ids: np.ndarray, t_ns: np.ndarray, pose6: np.ndarray, cov: np.ndarray) -> pa.Table:
    """poses.parquet from (K,) ids, (K,) times, (K, 6) poses and (K, 3, 3) covariances."""
    cols: dict[str, Any] = {"keyframe_id": ids.astype(np.int64), "t_ns": t_ns.astype(np.int64)}
    for i, name in enumerate(("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")):
        cols[name] = pose6[:, i]
    for name, (r, c) in zip(COVARIANCE_COLUMNS, zip(*_TRIU, strict=True), strict=True):
        cols[name] = cov[:, r, c]
    return pa.table(cols, schema=POSES_SCHEMA)


def factors_table(rows: list[dict[str, Any]], ids: np.ndarray) -> pa.Table:
    """factors.parquet from the front end's rows (keys are keyframe indices -> ids)."""
    z = np.array([r["z"] for r in rows]).reshape(-1, 3)
    cov = np.array([r["cov"] for r in rows]).reshape(-1, 3, 3)
    cols: dict[str, Any] = {
        "factor_id": np.arange(len(rows), dtype=np.int64),
        "type": pa.array([r["type"] for r in rows], pa.string()),
        "key_from": ids[[r["key_from"] for r in rows]].astype(np.int64),
        "key_to": ids[[r["key_to"] for r in rows]].astype(np.int64),
        "x_m": z[:, 0],
        "y_m": z[:, 1],
        "yaw_rad": z[:, 2],
    }
    for name, (r, c) in zip(COVARIANCE_COLUMNS, zip(*_TRIU, strict=True), strict=True):
        cols[name] = cov[:, r, c]
    cols["status"] = pa.array([r["status"] for r in rows], pa.string())
    cols["reason"] = pa.array([r["reason"] for r in rows], pa.string())
    cols["overlap_points"] = np.array([r["overlap"] for r in rows], dtype=np.int64)
    cols["rmse_m"] = pa.array([r["rmse"] for r in rows], pa.float64())
    cols["degenerate"] = pa.array([r.get("degenerate", "") for r in rows], pa.string())
    return pa.table(cols, schema=FACTORS_SCHEMA)


def tum_text(t_ns: np.ndarray, pose6: np.ndarray) -> bytes:
    """TUM trajectory ("t x y z qx qy qz qw", seconds and metres) for evo_ape / evo_traj."""
    q = quat_from_rpy(pose6[:, 3:6])
    lines = [
        f"{int(t) // 10**9}.{int(t) % 10**9:09d} " + " ".join(f"{v:.6f}" for v in (*p[:3], *qq))
        for t, p, qq in zip(t_ns, pose6, q, strict=True)
    ]
    return ("\n".join(lines) + "\n").encode()


def plot_points(pose_se2: np.ndarray, points: list[np.ndarray], max_points: int) -> pa.Table:
    """plot_points.parquet: the features registered with the estimated poses, every k-th
    point so that about `max_points` remain (what the `figures` stage draws in
    trajectory.png).

    Args:
        pose_se2: (K, 3) estimated poses.
        points: K arrays (N_k, 2) of base_link features.
        max_points: cap on the points kept (evenly subsampled; 0: none).
    """
    world = [transform_points(p, pts) for p, pts in zip(pose_se2, points, strict=True) if len(pts)]
    cloud = np.concatenate(world) if world and max_points > 0 else np.zeros((0, 2))
    cloud = cloud[:: max(1, len(cloud) // max(max_points, 1))]
    return pa.table({"x_m": cloud[:, 0], "y_m": cloud[:, 1]}, schema=PLOT_POINTS_SCHEMA)
