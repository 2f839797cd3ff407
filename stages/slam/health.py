"""What the slam stage can say about its own result without ground truth.

- The scan-matching points: horizontal features, their leading edges, the voxels those
  occupy, the points the outlier filter dropped, the keyframes over the point budget and
  the points they lost, the points kept; any keyframe over the budget is a warning.

- Scan matches proposed, accepted, rejected, and found degenerate (by direction: the body
  axis nearest the direction the scans left unconstrained, `sonarmap.stages.slam.degeneracy`).
- SLAM against dead reckoning. Both read the same AHRS heading and start at the same pose,
  so they can part only by what SLAM corrected: the odometry's position noise
  (`odom_chain_sigma_xy_m` per keyframe step), the heading bias's wander since the start
  (`heading_bias_walk_deg_sqrt_s`), chained along the dead-reckoned track
  (`sonarmap.stages.slam.pcm.chain_covariance`), and the DVL's scale error
  (`odom_scale_sigma`), which is not a random walk: fixed per body axis, it stretches each
  step's forward and sideways parts, so its error grows with the distance travelled along
  each body axis (`scale_drift_covariance`). Together that is the navigation's predicted
  drift; where the two trajectories part by more than its 99 %
  bound (sqrt(chi2(0.99, 2)) times the largest position standard deviation), either the
  navigation is worse than its noise model says, or scan matching went wrong: a warning.
- The odometry's scale error as SLAM estimates it (`odom_scale_sigma`: a state of the
  graph), per body axis. Beyond the prior's 99 % (sqrt(chi2(0.99, 1)) sigma) either the
  DVL is worse than the config says or the loops share a bias the state took for the
  DVL's (they come out short along walls seen at grazing incidence): a warning.
- No scan match accepted (mode `slam`, at least one proposed): the trajectory is dead
  reckoning's, bit for bit, where the user asked for SLAM. `fallback` says so with the
  reasons, and `run` prints it as its `trajectory:` line. Not a warning: a short or sparse
  recording (the first 45 s of the marina) falls back with nothing wrong in it.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from sonarmap.stages.slam.config import SlamConfig
from sonarmap.stages.slam.pcm import chain_covariance

__all__ = [
    "CHI2_99_2DOF",
    "SIGMAS_99_1DOF",
    "predicted_drift_m",
    "scale_drift_covariance",
    "slam_summary",
]

CHI2_99_2DOF = 9.210340371976184
"""chi2.ppf(0.99, 2) (a test checks it against scipy)."""

SIGMAS_99_1DOF = 2.5758293035489004
"""sqrt(chi2.ppf(0.99, 1)): a 99 % two-sided bound in standard deviations."""


def predicted_drift_m(config: SlamConfig, dr_se2: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """(K,) the largest position standard deviation [m] of dead reckoning relative to its
    first pose, by the navigation's noise model (see the module docstring)."""
    n = len(dr_se2)
    step = np.zeros((max(n - 1, 0), 3, 3))
    step[:, 0, 0] = step[:, 1, 1] = config.odom_chain_sigma_xy_m**2
    if config.heading_sigma_deg is not None and config.heading_bias_walk_deg_sqrt_s is not None:
        dt = np.maximum(np.diff(t_s), 0.0)
        step[:, 2, 2] = np.deg2rad(config.heading_bias_walk_deg_sqrt_s) ** 2 * dt
    else:
        step[:, 2, 2] = np.deg2rad(config.odom_sigma_yaw_deg) ** 2
    chain = chain_covariance(dr_se2, step)[:, :2, :2]
    if config.odom_scale_sigma is not None:
        chain = chain + scale_drift_covariance(dr_se2, config.odom_scale_sigma)
    return np.sqrt(np.linalg.eigvalsh(chain)[:, -1])


def scale_drift_covariance(dr_se2: np.ndarray, sigma: float) -> np.ndarray:
    """(K, 2, 2) world-frame position covariance of dead reckoning relative to its first
    pose from a per-axis odometry scale error (s_x, s_y), each N(0, sigma^2), fixed over the
    mission: pose k is off by sum_j R_j diag(s) b_j over the steps before it (b_j: step j in
    the body frame of pose j), i.e. by s_x a_x + s_y a_y with a_x = sum_j R_j e_x (b_j . e_x)
    (the forward parts of the steps, in the world) and a_y likewise."""
    out = np.zeros((len(dr_se2), 2, 2))
    if len(dr_se2) < 2:
        return out
    step = np.diff(dr_se2[:, :2], axis=0)
    c, s = np.cos(dr_se2[:-1, 2]), np.sin(dr_se2[:-1, 2])
    forward, port = np.stack([c, s], axis=1), np.stack([-s, c], axis=1)
    a_x = np.cumsum(forward * np.einsum("ij,ij->i", step, forward)[:, None], axis=0)
    a_y = np.cumsum(port * np.einsum("ij,ij->i", step, port)[:, None], axis=0)
    out[1:] = sigma**2 * (a_x[:, :, None] * a_x[:, None, :] + a_y[:, :, None] * a_y[:, None, :])
    return out


def _matches(rows: list[dict[str, Any]], kind: str) -> dict[str, Any]:
    mine = [r for r in rows if r["type"] == kind]
    directions = Counter(d for r in mine for d in r.get("degenerate", "").split(",") if d)
    return {
        "proposed": len(mine),
        "accepted": sum(r["status"] == "accepted" for r in mine),
        "rejected": sum(r["status"] == "rejected" for r in mine),
        "degenerate": sum(bool(r.get("degenerate")) for r in mine),
        "degenerate_by_direction": dict(sorted(directions.items())),
    }


def slam_summary(
    config: SlamConfig,
    rows: list[dict[str, Any]],
    ids: np.ndarray,
    dr_se2: np.ndarray,
    slam_se2: np.ndarray,
    t_s: np.ndarray,
    fell_back: bool,
    point_counts: dict[str, int] | None = None,
    odometry_scale: np.ndarray | None = None,
) -> dict[str, Any]:
    """The stage's summary.json: matches, SLAM vs dead reckoning, the scan-matching points
    (`sonarmap.stages.slam.points.counted_keyframe_points`: what thinning and the outlier
    filter dropped), warnings (one line each)."""
    ssm, loop = _matches(rows, "ssm"), _matches(rows, "loop")
    gap = np.hypot(*(slam_se2[:, :2] - dr_se2[:, :2]).T)
    bound = np.sqrt(CHI2_99_2DOF) * predicted_drift_m(config, dr_se2, t_s)
    excess = np.where(bound > 0, gap / np.where(bound > 0, bound, 1.0), 0.0)
    worst = int(np.argmax(excess)) if len(excess) else 0
    drift = {
        "max_gap_m": round(float(gap.max()), 4) if len(gap) else 0.0,
        "final_gap_m": round(float(gap[-1]), 4) if len(gap) else 0.0,
        "worst_keyframe_id": int(ids[worst]) if len(ids) else None,
        "gap_at_worst_m": round(float(gap[worst]), 4) if len(gap) else 0.0,
        "predicted_bound_at_worst_m": round(float(bound[worst]), 4) if len(bound) else 0.0,
        "exceeds_prediction": bool(len(excess) and excess[worst] > 1.0),
    }
    warnings = []
    if drift["exceeds_prediction"] and config.mode == "slam":
        found = ssm["degenerate"] + loop["degenerate"]
        warnings.append(
            f"slam: SLAM and dead reckoning part by {drift['gap_at_worst_m']:.2f} m at keyframe"
            f" {drift['worst_keyframe_id']}, more than the {drift['predicted_bound_at_worst_m']:.2f}"
            " m the navigation's noise model allows there (99 %): the navigation is worse than"
            " slam.odom_chain_sigma_xy_m and slam.odom_scale_sigma say, or scan matching went"
            " wrong"
            f" ({found} of {ssm['proposed'] + loop['proposed']} matches found degenerate);"
            " compare the two trajectories before trusting the map"
        )
    scale = _scale_error(config, odometry_scale)
    if scale is not None and scale["beyond_prior"] and config.mode == "slam":
        warnings.append(
            f"slam: SLAM reads the odometry's scale error as {100 * scale['forward']:+.1f} %"
            f" forward, {100 * scale['sideways']:+.1f} % sideways, more than"
            f" slam.odom_scale_sigma ({100 * scale['prior_sigma']:.1f} %) allows (99 %): the"
            " DVL is worse than that says (set it from the DVL's datasheet or calibration),"
            " or the loops share a bias the state took for the DVL's (long walls seen at"
            " grazing incidence); compare the two trajectories before trusting the map"
        )
    proposed = ssm["proposed"] + loop["proposed"]
    fallback = ""
    if fell_back and config.mode == "slam" and proposed:
        reasons = Counter(r["reason"] for r in rows if r["status"] == "rejected" and r["reason"])
        why = ", ".join(f"{reason}: {n}" for reason, n in reasons.most_common())
        fallback = (
            f"dead reckoning: none of the {proposed} scan matches proposed was accepted"
            f" ({why}), so the poses are the navigation's"
        )
    # The share the outlier filter drops is recorded, not warned: at the front end's stated
    # false-alarm rate a sparse scene (lone pilings in open water) has most of its points
    # isolated by design, and a flood is the front end's to warn about.
    points = dict(point_counts or {})
    over, lost = points.get("over_budget_keyframes", 0), points.get("over_budget_points", 0)
    if config.mode == "slam" and over:
        warnings.append(
            f"slam: {over} of {len(ids)} keyframes held more than"
            f" slam.max_points_per_keyframe ({config.max_points_per_keyframe}) scan-matching"
            f" points and were thinned on coarser voxels ({lost:,} points merged): the"
            " features are flooded; check the features stage's detections"
        )
    return {
        "mode": config.mode,
        "points": points,
        "keyframes": len(ids),
        "fell_back_to_dead_reckoning": fell_back,
        "fallback": fallback,
        "scan_matching": {"ssm": ssm, "loop": loop},
        "dead_reckoning_vs_slam": drift,
        "odometry_scale_error": scale,
        "warnings": warnings,
    }


def _scale_error(config: SlamConfig, estimate: np.ndarray | None) -> dict[str, Any] | None:
    """The scale state's estimate against its prior; None without one."""
    if estimate is None or config.odom_scale_sigma is None:
        return None
    sigma = config.odom_scale_sigma
    return {
        "forward": round(float(estimate[0]), 5),
        "sideways": round(float(estimate[1]), 5),
        "prior_sigma": sigma,
        "beyond_prior": bool(np.max(np.abs(estimate)) > SIGMAS_99_1DOF * sigma),
    }
