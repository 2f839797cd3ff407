"""What a run can say about its own map without ground truth (issue 37, item 6).

A field recording has no mesh and no true poses, so the error figures of
`sonarmap.stages.evaluate.stage` are skipped. These figures need neither. They read the map, the
keyframes and the pose graph that the run itself produced:

- per class, how many inferred points stand in a world column that also holds fused
  (directly measured) evidence, and how many of those agree with it within a height
  tolerance: the columns with evidence are the only places where a prediction can be
  checked at all;
- keyframes that contributed fused points;
- loop closures proposed, accepted and rejected (with the reasons), and the residuals of
  the scan matches that were accepted;
- how far dead reckoning drifted from the SLAM trajectory, and (from the slam stage's
  summary, `sonarmap.stages.slam.health`) whether that is more than the navigation's
  noise model predicts, with the scan matches found degenerate and in which direction,
  and slam's warnings.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.stages.kernels.voxels import column_ids

__all__ = ["column_agreement", "trust_markdown", "trust_report"]


def column_agreement(
    inferred_xyz_m: np.ndarray,
    fused_xyz_m: np.ndarray,
    cell_m: float,
    height_tolerance_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Which inferred points have fused evidence in their world column, and agree with it.

    Args:
        inferred_xyz_m: (n, 3) inferred points, world frame [m].
        fused_xyz_m: (m, 3) fused points, world frame [m].
        cell_m: side of a column's square cell [m].
        height_tolerance_m: an inferred point agrees when a fused point of its column lies
            within this height of it.

    Returns:
        (has_evidence, agrees): two (n,) bool arrays; agrees implies has_evidence.
    """
    q = np.asarray(inferred_xyz_m, np.float64).reshape(-1, 3)
    f = np.asarray(fused_xyz_m, np.float64).reshape(-1, 3)
    has = np.zeros(len(q), bool)
    agrees = np.zeros(len(q), bool)
    if len(q) == 0 or len(f) == 0:
        return has, agrees
    f_col = column_ids(f[:, :2], cell_m)
    q_col = column_ids(q[:, :2], cell_m)
    order = np.lexsort((f[:, 2], f_col))
    f_col, f_z = f_col[order], f[order, 2]
    lo = np.searchsorted(f_col, q_col, side="left")
    hi = np.searchsorted(f_col, q_col, side="right")
    has = hi > lo
    # One sorted key for all columns: column rank times more than the height span, plus the
    # height. A query's key, its height clipped to just outside the span, falls inside its
    # own column's run of keys, so its nearest fused height is at pos - 1 or pos.
    z0, z_span = float(f_z.min()), float(np.ptp(f_z))
    columns = np.unique(f_col)
    span = z_span + 2.0
    key = np.searchsorted(columns, f_col) * span + (f_z - z0)
    q_rank = np.searchsorted(columns, q_col).clip(0, len(columns) - 1)
    q_key = q_rank * span + np.clip(q[:, 2] - z0, -0.5, z_span + 0.5)
    pos = np.searchsorted(key, q_key)
    best = np.full(len(q), np.inf)
    for candidate in (pos - 1, pos):
        inside = (candidate >= lo) & (candidate < hi)
        d = np.abs(f_z[np.where(inside, candidate, 0)] - q[:, 2])
        best = np.where(inside, np.minimum(best, d), best)
    agrees = has & (best <= height_tolerance_m)
    return has, agrees


def _share(part: int, whole: int) -> float | None:
    return round(part / whole, 4) if whole else None


def _strings(table: pa.Table, column: str) -> np.ndarray:
    """A string column as an object array (one conversion, no Python list between)."""
    return np.asarray(table.column(column).to_numpy(zero_copy_only=False), dtype=object)


def _inference_agreement(
    map_table: pa.Table, source: np.ndarray, cell_m: float, height_tolerance_m: float
) -> dict[str, Any]:
    names = ("x_m", "y_m", "z_m")
    xyz = np.stack([map_table.column(c).to_numpy() for c in names], axis=1).reshape(-1, 3)
    classes = _strings(map_table, "class_name")
    inferred = source == "inferred"
    has, agrees = column_agreement(
        xyz[inferred], xyz[source == "fused"], cell_m, height_tolerance_m
    )
    per_class: dict[str, Any] = {}
    for name in sorted(set(classes[inferred].tolist())):
        mine = classes[inferred] == name
        n, n_has, n_agree = int(mine.sum()), int(has[mine].sum()), int(agrees[mine].sum())
        per_class[name] = {
            "inferred_points": n,
            "with_fused_evidence": n_has,
            "agreeing": n_agree,
            "checkable_share": _share(n_has, n),
            "agreeing_share_of_checkable": _share(n_agree, n_has),
        }
    return {"cell_m": cell_m, "height_tolerance_m": height_tolerance_m, "per_class": per_class}


def _loop_closures(factors: pa.Table) -> dict[str, Any]:
    kind, status, reason = (_strings(factors, c) for c in ("type", "status", "reason"))
    rmse = factors.column("rmse_m").to_numpy(zero_copy_only=False).astype(np.float64)
    out: dict[str, Any] = {}
    for name in ("loop", "ssm"):
        mine = kind == name
        accepted = mine & (status == "accepted")
        fit = rmse[accepted & np.isfinite(rmse)]
        out[name] = {
            "proposed": int(mine.sum()),
            "accepted": int(accepted.sum()),
            "rejected": int((mine & (status == "rejected")).sum()),
            "rejected_by_reason": dict(
                sorted(Counter(reason[mine & (status == "rejected")]).items())
            ),
            "icp_rmse_m": {
                "median": round(float(np.median(fit)), 4) if len(fit) else None,
                "p90": round(float(np.percentile(fit, 90)), 4) if len(fit) else None,
                "max": round(float(fit.max()), 4) if len(fit) else None,
            },
        }
    return out


def _drift(keyframes: pa.Table, poses: pa.Table) -> dict[str, Any]:
    dr_ids = keyframes.column("keyframe_id").to_numpy()
    ids, in_dr, in_slam = np.intersect1d(
        dr_ids, poses.column("keyframe_id").to_numpy(), return_indices=True
    )
    if len(ids) == 0:
        return {"n_keyframes": 0}

    def xy(table: pa.Table, rows: np.ndarray) -> np.ndarray:
        return np.stack(
            [table.column("x_m").to_numpy()[rows], table.column("y_m").to_numpy()[rows]], 1
        )

    gap = np.linalg.norm(xy(keyframes, in_dr) - xy(poses, in_slam), axis=1)
    steps = np.linalg.norm(np.diff(xy(poses, in_slam), axis=0), axis=1)
    travelled = float(steps.sum())
    return {
        "n_keyframes": len(ids),
        "final_m": round(float(gap[-1]), 4),
        "max_m": round(float(gap.max()), 4),
        "path_length_m": round(travelled, 3),
        "final_share_of_path": _share(float(gap[-1]), travelled) if travelled > 0 else None,
    }


def trust_report(
    map_table: pa.Table,
    keyframes: pa.Table,
    poses: pa.Table,
    factors: pa.Table | None,
    cell_m: float,
    height_tolerance_m: float,
    slam_summary: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The run's self-consistency figures (see the module docstring), as a JSON dict."""
    source = _strings(map_table, "source")
    fused_kf = map_table.column("keyframe_id").to_numpy()[source == "fused"]
    slam = slam_summary or {}
    return {
        "slam": {
            "fell_back_to_dead_reckoning": slam.get("fell_back_to_dead_reckoning"),
            "degenerate_matches": {
                name: {
                    "found": sm.get("degenerate"),
                    "by_direction": sm.get("degenerate_by_direction"),
                }
                for name, sm in (slam.get("scan_matching") or {}).items()
            },
            "drift_check": slam.get("dead_reckoning_vs_slam"),
            "odometry_scale_error": slam.get("odometry_scale_error"),
        },
        "warnings": list(slam.get("warnings") or []),
        "inference": _inference_agreement(map_table, source, cell_m, height_tolerance_m),
        "keyframes_with_fused_points": len(np.unique(fused_kf)),
        "keyframes": int(keyframes.num_rows),
        "scan_matching": None if factors is None else _loop_closures(factors),
        "dead_reckoning_vs_slam": _drift(keyframes, poses),
    }


def _cell(value: Any) -> str:
    if value is None:
        return "-"
    return f"{value:.1%}" if isinstance(value, float) else str(value)


def _metres(value: Any) -> str:
    return "-" if value is None else f"{value:.3f}"


def trust_markdown(trust: dict[str, Any] | None) -> list[str]:
    """The report's "Trust" section: the figures of `trust_report`, no ground truth needed."""
    if not trust:
        return []
    inference = trust["inference"]
    lines = [
        "## Trust (no ground truth needed)",
        "",
        f"Inferred points checked against the fused points of their own world column"
        f" ({inference['cell_m']} m cells): checkable where the column holds fused points,"
        f" agreeing where one lies within {inference['height_tolerance_m']} m in height.",
        "",
        "| class | inferred points | checkable | agreeing of checkable |",
        "|---|---:|---:|---:|",
    ]
    for name, row in inference["per_class"].items():
        lines.append(
            f"| {name} | {row['inferred_points']} | {_cell(row['checkable_share'])}"
            f" | {_cell(row['agreeing_share_of_checkable'])} |"
        )
    lines += [
        "",
        f"- keyframes with fused points: {trust['keyframes_with_fused_points']}"
        f" of {trust['keyframes']}",
    ]
    for name, label in (("loop", "loop closures"), ("ssm", "sequential scan matches")):
        sm = (trust.get("scan_matching") or {}).get(name)
        if sm:
            reasons = ", ".join(f"{k}: {v}" for k, v in sm["rejected_by_reason"].items())
            fit = sm["icp_rmse_m"]
            lines.append(
                f"- {label}: {sm['proposed']} proposed, {sm['accepted']} accepted,"
                f" {sm['rejected']} rejected{f' ({reasons})' if reasons else ''};"
                f" ICP fit RMSE of the accepted: median {_metres(fit['median'])} m,"
                f" p90 {_metres(fit['p90'])} m"
            )
    drift = trust.get("dead_reckoning_vs_slam") or {}
    if drift.get("n_keyframes"):
        lines.append(
            f"- dead reckoning vs SLAM: {drift['final_m']} m apart at the end,"
            f" at most {drift['max_m']} m, over {drift['path_length_m']} m of path"
        )
    lines += _slam_lines(trust.get("slam") or {})
    lines += [f"- **warning:** {w}" for w in trust.get("warnings") or []]
    return [*lines, ""]


def _slam_lines(slam: dict[str, Any]) -> list[str]:
    """The slam stage's own checks: degenerate matches, the drift check, the fallback."""
    lines = []
    for name, label in (("ssm", "sequential scan matches"), ("loop", "loop closures")):
        found = (slam.get("degenerate_matches") or {}).get(name) or {}
        if found.get("found"):
            by = ", ".join(f"{k}: {v}" for k, v in (found.get("by_direction") or {}).items())
            lines.append(
                f"- {label} found degenerate (free along one direction of the body frame,"
                f" the odometry carries it): {found['found']} ({by})"
            )
    check = slam.get("drift_check") or {}
    if check.get("predicted_bound_at_worst_m") is not None and "gap_at_worst_m" in check:
        verdict = "more than" if check.get("exceeds_prediction") else "within"
        lines.append(
            f"- SLAM vs the navigation's predicted drift: {check['gap_at_worst_m']} m apart at"
            f" keyframe {check.get('worst_keyframe_id')}, {verdict} its 99 % bound there"
            f" ({check['predicted_bound_at_worst_m']} m)"
        )
    scale = slam.get("odometry_scale_error") or {}
    if scale.get("prior_sigma"):
        lines.append(
            f"- the odometry's scale error as SLAM estimates it: {100 * scale['forward']:+.2f} %"
            f" forward, {100 * scale['sideways']:+.2f} % sideways (prior"
            f" {100 * scale['prior_sigma']:.1f} %{', beyond its 99 %' if scale.get('beyond_prior') else ''})"
        )
    if slam.get("fell_back_to_dead_reckoning"):
        lines.append("- no scan match was accepted: the trajectory is dead reckoning's")
    return lines
