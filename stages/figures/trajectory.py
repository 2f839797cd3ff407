"""`trajectory.png`: the SLAM estimate, dead reckoning and ground truth from above, with the
features registered with the estimate and the accepted loop closures (stage `slam`'s data)."""

from __future__ import annotations

import numpy as np

from sonarmap.stages.kernels.figure_png import png_bytes
from sonarmap.stages.kernels.mesh_metrics import se2_alignment

__all__ = ["trajectory_png"]


def trajectory_png(
    pose_se2: np.ndarray,
    dr_se2: np.ndarray,
    gt_se2: np.ndarray | None,
    cloud: np.ndarray,
    loops: np.ndarray,
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
        cloud: (N, 2) world features registered with the estimate (slam's
            `plot_points.parquet`, already thinned).
        loops: (L, 2) keyframe indices of accepted loop closures.
        title: figure title.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    est_xy, dr_xy = pose_se2[:, :2], dr_se2[:, :2]
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
    return png_bytes(fig)
