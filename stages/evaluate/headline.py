"""The headline map error: the figure a reader of the first table takes away.

The raw error of a SLAM map to the truth is dominated by a common rotation and offset
that sonar-only SLAM cannot observe (a constant heading bias of the navigation turns
every pose alike). Like evo's APE, the headline therefore leads with the error after
the SE(2) alignment of the SLAM trajectory to the truth, names that alignment, and
keeps the raw figure beside it. A run on ground-truth poses needs no alignment and
says so instead.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

import numpy as np
import pyarrow as pa

from sonarmap.stages.kernels.poses import pose_matrices

__all__ = [
    "Frame",
    "headline_errors",
    "headline_label",
    "poses_are_ground_truth",
    "visibility_poses",
]

Frame = Literal["aligned", "ground_truth_poses", "raw"]
"""aligned: SE(2)-aligned SLAM map; ground_truth_poses: mapped with the true poses;
raw: no ground-truth poses to align with (the raw figure is all there is)."""

_POSE_COLUMNS = ("x_m", "y_m", "yaw_rad")


def poses_are_ground_truth(keyframes: pa.Table, poses: pa.Table, atol: float = 1e-9) -> bool:
    """True when every SLAM pose equals the keyframe's ground-truth pose (x, y, yaw).

    `slam.mode=ground_truth` copies the true poses; any estimate differs from them.
    """
    if "gt_x_m" not in keyframes.column_names or keyframes.column("gt_x_m").null_count:
        return False
    if poses.num_rows != keyframes.num_rows or poses.num_rows == 0:
        return False
    order_k = np.argsort(keyframes.column("keyframe_id").to_numpy(), kind="stable")
    order_p = np.argsort(poses.column("keyframe_id").to_numpy(), kind="stable")
    for col in _POSE_COLUMNS:
        truth = keyframes.column(f"gt_{col}").to_numpy(zero_copy_only=False)[order_k]
        est = poses.column(col).to_numpy(zero_copy_only=False)[order_p]
        if not np.allclose(est, truth, rtol=0.0, atol=atol):
            return False
    return True


def headline_label(frame: Frame, rotation_deg: float | None) -> str:
    """Column label of the headline median error, naming how it was obtained."""
    if frame == "aligned":
        return f"median error m, SE(2)-aligned (rotation {rotation_deg:.2f}°)"
    if frame == "ground_truth_poses":
        return "median error m, ground-truth poses (no alignment)"
    return "median error m, raw (no ground-truth poses to align)"


def headline_errors(
    errors: Mapping[str, Any], aligned: Mapping[str, Any] | None, on_ground_truth: bool
) -> dict[str, Any]:
    """The headline figures of both maps from evaluate's `errors` and `errors_aligned`.

    Args:
        errors: {"standard"|"semantic": error_stats} at the mapped positions.
        aligned: `errors_aligned` ({"standard", "semantic", "rotation_deg", ...}) or None.
        on_ground_truth: the SLAM poses are the true poses (`poses_are_ground_truth`).

    Returns:
        {"frame": Frame, "label": str, "rotation_deg": float | None,
        "median_m": {map: float | None}, "raw_median_m": {map: float | None}}.
    """
    raw = {name: (errors.get(name) or {}).get("median_m") for name in ("standard", "semantic")}
    frame: Frame = "raw"
    rotation = None
    median = dict(raw)
    if on_ground_truth:
        frame = "ground_truth_poses"
    elif aligned:
        frame = "aligned"
        rotation = float(aligned["rotation_deg"])
        median = {name: (aligned.get(name) or {}).get("median_m") for name in raw}
    return {
        "frame": frame,
        "label": headline_label(frame, rotation),
        "rotation_deg": rotation,
        "median_m": median,
        "raw_median_m": raw,
    }


def visibility_poses(keyframes: pa.Table, poses: pa.Table, T_base_sonar: np.ndarray) -> np.ndarray:
    """(k, 4, 4) T_world_sonar of every keyframe: ground truth when complete, else SLAM."""
    gt = keyframes.column("gt_x_m")
    table, prefix = (keyframes, "gt_") if gt.null_count == 0 and len(gt) else (poses, "")
    _, T = pose_matrices(table, prefix)
    return T @ T_base_sonar
