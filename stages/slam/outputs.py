"""Output files of the `slam` stage: poses and factors tables, TUM trajectory, PNG plot."""

from __future__ import annotations

import io
from typing import Any

import numpy as np
import pyarrow as pa

from schemas.slam import COVARIANCE_COLUMNS, FACTORS_SCHEMA, POSES_SCHEMA
from stages.kernels.geometry import quat_from_rpy
from stages.kernels.mesh_metrics import se2_alignment
from stages.slam.scan_matching import transform_points

__all__ = ["factors_table", "plot_png", "poses_table", "tum_text"]

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
    return pa.table(cols, schema=FACTORS_SCHEMA)


def tum_text(t_ns: np.ndarray, pose6: np.ndarray) -> bytes:
    """TUM trajectory ("t x y z qx qy qz qw", seconds and metres) for evo_ape / evo_traj."""
    q = quat_from_rpy(pose6[:, 3:6])
    lines = [
        f"{int(t) // 10**9}.{int(t) % 10**9:09d} " + " ".join(f"{v:.6f}" for v in (*p[:3], *qq))
        for t, p, qq in zip(t_ns, pose6, q, strict=True)
    ]
    return ("\n".join(lines) + "\n").encode()


def plot_png(
    pose_se2: np.ndarray,
    dr_se2: np.ndarray,
    gt_se2: np.ndarray | None,
    points: list[np.ndarray],
    loops: np.ndarray,
    max_points: int,
    title: str,
) -> bytes:
    """Top-down PNG: features registered with the estimate, trajectories, loop closures.

    With ground truth, the estimate (with its features and loops) and the dead reckoning are
    each moved onto the truth by their least-squares rigid fit (the ATE's alignment; the
    start pose and heading are unobservable, so unaligned tracks would show that offset
    rather than their shape), the legend gives each one's ATE, and a lower panel plots
    each keyframe's position error after that alignment.

    Args:
        pose_se2, dr_se2: (K, 3) estimated and dead-reckoning poses.
        gt_se2: (K, 3) ground truth or None.
        points: K arrays (N_k, 2) of base_link features.
        loops: (L, 2) keyframe indices of accepted loop closures.
        max_points: cap on plotted feature points (evenly subsampled).
        title: figure title.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    est_xy, dr_xy = pose_se2[:, :2], dr_se2[:, :2]
    world = [transform_points(p, pts) for p, pts in zip(pose_se2, points, strict=True) if len(pts)]
    cloud = np.concatenate(world) if world and max_points > 0 else np.zeros((0, 2))
    cloud = cloud[:: max(1, len(cloud) // max(max_points, 1))]
    label_est, label_dr = "estimate", "dead reckoning"
    if gt_se2 is not None:
        truth = gt_se2[:, :2]
        rot, shift = se2_alignment(est_xy, truth)
        est_xy, cloud = est_xy @ rot.T + shift, cloud @ rot.T + shift
        rot, shift = se2_alignment(dr_xy, truth)
        dr_xy = dr_xy @ rot.T + shift
        err_est = np.linalg.norm(est_xy - truth, axis=1)
        err_dr = np.linalg.norm(dr_xy - truth, axis=1)
        label_est += f" (ATE {np.sqrt(np.mean(err_est**2)):.3f} m)"
        label_dr += f" (ATE {np.sqrt(np.mean(err_dr**2)):.3f} m)"
        fig = Figure(figsize=(7, 9), dpi=110)
        ax, ax_err = fig.subplots(2, 1, gridspec_kw={"height_ratios": [3.2, 1]})
    else:
        fig = Figure(figsize=(7, 7), dpi=110)
        ax, ax_err = fig.add_subplot(), None
    if len(cloud):
        ax.plot(cloud[:, 0], cloud[:, 1], ",", c="0.6", label="features")
    for n, (a, b) in enumerate(loops):
        ax.plot(*est_xy[[a, b]].T, "-", c="tab:red", lw=0.6, label="loop" if n == 0 else None)
    ax.plot(dr_xy[:, 0], dr_xy[:, 1], "--", c="tab:orange", lw=1.0, label=label_dr)
    ax.plot(est_xy[:, 0], est_xy[:, 1], "-", c="tab:blue", lw=1.6, label=label_est)
    if gt_se2 is not None:  # on top and thin, so where the estimate covers it shows
        ax.plot(gt_se2[:, 0], gt_se2[:, 1], "-", c="tab:green", lw=0.7, label="ground truth")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title + (", aligned to the ground truth" if gt_se2 is not None else ""))
    ax.legend(loc="best", fontsize=8)
    if ax_err is not None:
        ax_err.plot(err_dr, "--", c="tab:orange", lw=1.0, label="dead reckoning")
        ax_err.plot(err_est, "-", c="tab:blue", lw=1.2, label="estimate")
        ax_err.set_xlabel("keyframe")
        ax_err.set_ylabel("position error [m]")
        ax_err.set_xlim(0, max(len(err_est) - 1, 1))
        ax_err.set_ylim(bottom=0)
        ax_err.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()
