"""Incremental SLAM front end: SSM, NSSM and PCM over keyframes on one iSAM2 graph.

Per keyframe (paper Sec. IV.A): an odometry factor (through the mission's odometry scale
error, a state: `PlanarPoseGraph.add_scaled_odometry`), an absolute heading factor (mode
slam; through a random-walk bias state, `PlanarPoseGraph.add_biased_heading`),
sequential scan matching against the previous few keyframes and, once far enough from
the start, non-sequential scan matching (loop closure) against older keyframes, with
PCM and the final re-registration of every loop: `sonarmap.stages.slam.loops`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sonarmap.stages.slam.config import SlamConfig
from sonarmap.stages.slam.degeneracy import constrained_covariance, degeneracy
from sonarmap.stages.slam.loops import LoopCandidate, LoopClosures
from sonarmap.stages.slam.pcm import chi2_quantile
from sonarmap.stages.slam.pose_graph import (
    PlanarPoseGraph,
    se2_between,
    se2_compose,
    se2_log,
    wrap_angle,
)
from sonarmap.stages.slam.scan_matching import (
    MatchResult,
    TargetIndex,
    match_scans,
    transform_points,
    voxel_downsample,
)

__all__ = ["SlamResult", "run_slam"]

_FREE_M2 = 1e6
_LONGEST_STEP_S = 3600.0
"""A step between keyframes longer than this is a gap in the recording (a clock jump, which
the reader warns about), not that long under way: its odometry noise is this long's. GTSAM's
solver fails on a step years long (sigma 73 m beside millimetres), and the dead-reckoned
motion across a gap is what the navigation reported, not a DVL's drift over years."""
"""Variance [m^2] of the position part of a heading-only prior (unconstrained)."""


def _diag_cov(sigma_xy_m: float, sigma_yaw_deg: float) -> np.ndarray:
    return np.diag([sigma_xy_m**2, sigma_xy_m**2, np.deg2rad(sigma_yaw_deg) ** 2])


@dataclass
class SlamResult:
    """Poses (K, 3) (x_m, y_m, yaw_rad), covariances (K, 3, 3), factor rows (dicts),
    whether no scan match was accepted, so the poses are dead reckoning's, and the
    odometry's scale error (s_x, s_y) as the graph estimates it (None without the state)."""

    poses: np.ndarray
    covariances: np.ndarray
    factors: list[dict[str, Any]] = field(default_factory=list)
    fell_back: bool = False
    odometry_scale: np.ndarray | None = None


class _FrontEnd(LoopClosures):
    """Incremental SSM + NSSM + PCM over keyframes, feeding one `PlanarPoseGraph`."""

    def __init__(self, config: SlamConfig, points: list[np.ndarray]) -> None:
        self.cfg = config
        self.points = points
        self.reach_m = np.array([np.hypot(*p.T).max() if len(p) else 0.0 for p in points])
        self.graph = PlanarPoseGraph()
        self.est = np.zeros((0, 3))
        self._clouds: dict[tuple[int, int, int], np.ndarray] = {}
        self._clouds_of = self.est  # the estimate the cached clouds were built from
        self._indexes: dict[int, TargetIndex] = {}  # id of a cached cloud -> its index
        self.edge_covs: list[np.ndarray] = []
        self.rows: list[dict[str, Any]] = []
        self.queue: list[LoopCandidate] = []
        self.icp_cov = _diag_cov(config.icp_sigma_xy_m, config.icp_sigma_yaw_deg)
        # The chain covariance (loop search windows, gates, PCM) must also cover the drift
        # of the scale error, which the scaled odometry factors leave out of their noise.
        self.chain_odom_cov = _diag_cov(config.odom_chain_sigma_xy_m, config.odom_sigma_yaw_deg)
        self.odom_info = np.linalg.inv(self.chain_odom_cov)
        self.loop_cov = _diag_cov(config.loop_sigma_xy_m, config.loop_sigma_yaw_deg)
        self.heading_dt_s = 0.0
        self.bias_key: int | None = None  # the last keyframe with a heading-bias state

    def _biased_heading(
        self, k: int, nav: np.ndarray, walk_rad: float, bias_rad: float, graph: PlanarPoseGraph
    ) -> None:
        c = self.cfg
        assert c.heading_sigma_deg is not None
        graph.add_biased_heading(
            k,
            nav,
            float(np.deg2rad(c.heading_sigma_deg)),
            walk_rad,
            bias_rad,
            float(np.deg2rad(c.heading_first_bias_sigma_deg)),
        )

    def _odometry_cov(self, dt_s: float) -> np.ndarray:
        """(3, 3) white noise of one odometry step: the DVL's position noise grows with the
        square root of the step's duration, the yaw's is that of two AHRS readings."""
        c = self.cfg
        step_s = min(max(dt_s, 0.01), _LONGEST_STEP_S)
        return _diag_cov(c.odom_sigma_xy_m_sqrt_s * np.sqrt(step_s), c.odom_sigma_yaw_deg)

    def _odometry(self, row: dict[str, Any], graph: PlanarPoseGraph) -> None:
        a, b, z, cov = row["key_from"], row["key_to"], row["z"], row["cov"]
        if row.get("scaled"):
            graph.add_scaled_odometry(a, b, z, cov)
        else:
            graph.add_between(a, b, z, cov)

    def _row(self, kind: str, a: int, b: int, z: np.ndarray, cov: np.ndarray, **kw: Any) -> int:
        row = {"type": kind, "key_from": a, "key_to": b, "z": np.asarray(z, float), "cov": cov}
        row.update(
            {"status": "accepted", "reason": "", "overlap": 0, "rmse": None, "degenerate": ""}
        )
        row.update(kw)
        self.rows.append(row)
        return len(self.rows) - 1

    def _update(self, extra_iterations: int = 0) -> None:
        self.graph.update(extra_iterations)
        self.est = self.graph.poses()

    def _cloud(self, frames: range, anchor: int) -> np.ndarray:
        """Frames' points in the frame of `anchor` from the current estimate, downsampled.

        Built once per estimate: the loop re-registration asks for the same target cloud
        for every loop into one stretch of the track (callers never modify a cloud).
        """
        if self._clouds_of is not self.est:
            self._clouds, self._clouds_of, self._indexes = {}, self.est, {}
        key = (frames.start, frames.stop, anchor)
        if key not in self._clouds:
            parts = [
                transform_points(se2_between(self.est[anchor], self.est[j]), self.points[j])
                for j in frames
                if len(self.points[j])
            ]
            self._clouds[key] = (
                voxel_downsample(np.concatenate(parts), self.cfg.point_resolution_m)
                if parts
                else np.zeros((0, 2))
            )
        return self._clouds[key]

    def _index(self, cloud: np.ndarray) -> np.ndarray | TargetIndex:
        """A cached cloud's `TargetIndex` (its voxel map and k-d tree built once for all
        matches against it while the estimate stands); another array as it is."""
        if not any(c is cloud for c in self._clouds.values()):
            return cloud
        if id(cloud) not in self._indexes:
            self._indexes[id(cloud)] = TargetIndex(cloud)
        return self._indexes[id(cloud)]

    def _floor(self, cov: np.ndarray, floor: np.ndarray) -> np.ndarray:
        """Scale an ICP covariance up to at least the determinant of `floor`.

        The authors replace a too-small covariance by the default (`floor_mode` "replace");
        "scale" keeps the Hessian's shape, whose x-yaw correlation carries the lever arm
        between the keyframe and the matched structure.
        """
        det, det_floor = np.linalg.det(cov), np.linalg.det(floor)
        if not np.all(np.isfinite(cov)) or det <= 0:
            return floor
        if det >= det_floor:
            return cov
        return (
            floor if self.cfg.covariance_floor == "replace" else cov * (det_floor / det) ** (1 / 3)
        )

    def _match(
        self, source: np.ndarray, target: np.ndarray, guess: np.ndarray, half: np.ndarray
    ) -> MatchResult:
        c = self.cfg
        return match_scans(
            source,
            self._index(target),
            guess,
            half,
            c.grid_resolution_m,
            c.point_noise_m,
            c.max_correspondence_m,
            c.icp_max_iterations,
            c.search_max_points,
            c.search_tie_fraction,
            c.icp_effective_samples,
        )

    def _check(self, m: MatchResult, guess: np.ndarray, max_t: float, max_deg: float) -> str:
        dev = se2_between(guess, m.pose)
        if np.hypot(dev[0], dev[1]) > max_t or abs(dev[2]) > np.deg2rad(max_deg):
            return "deviation from odometry"
        if m.overlap < self.cfg.min_overlap_points:
            return "overlap"
        return ""

    def _constrain(
        self, pose: np.ndarray, cov: np.ndarray, source: np.ndarray, target: np.ndarray
    ) -> tuple[np.ndarray, str, int]:
        """`cov` made free along the direction the match leaves unconstrained
        (`sonarmap.stages.slam.degeneracy`): (covariance, its label, 1 or 0)."""
        c = self.cfg
        if c.degeneracy_min_ratio is None:
            return cov, "", 0
        index = self._index(target)
        if not isinstance(index, TargetIndex):
            index = TargetIndex(index)
        found = degeneracy(
            source, index.points, index.tree, pose, c.point_noise_m, c.degeneracy_min_ratio
        )
        # How far off the wall's direction may be (opt-in: see docs/slam.md, Known limits).
        tilt = 0.0 if c.degeneracy_tilt_deg is None else np.tan(np.deg2rad(c.degeneracy_tilt_deg))
        return constrained_covariance(cov, found, pose[:2], float(tilt)), found.label, found.count

    def _step_cov(self, odometry: np.ndarray, dt_s: float) -> np.ndarray:
        """(3, 3) covariance of the odometry over one step: its white noise for the step's
        duration plus the scale error's share of the step's length (per axis)."""
        cov = self._odometry_cov(dt_s)
        if self.cfg.odom_scale_sigma is not None:
            cov = cov + np.diag([*(self.cfg.odom_scale_sigma * odometry[:2]) ** 2, 0.0])
        return cov

    def _gate(
        self, pose: np.ndarray, guess: np.ndarray, cov: np.ndarray, odo: np.ndarray, free: int
    ) -> str:
        """Why a sequential match disagrees with the odometry of its step ("" if it does
        not): Mahalanobis distance over the directions it constrains (`ssm_gate_probability`)."""
        p = self.cfg.ssm_gate_probability
        if p is None:
            return ""
        dev = se2_log(se2_between(guess, pose))
        if dev @ np.linalg.solve(odo + cov, dev) > chi2_quantile(p, 3 - free):
            return "inconsistent with odometry"
        return ""

    def start(self, pose: np.ndarray) -> None:
        cov = _diag_cov(self.cfg.prior_sigma_xy_m, self.cfg.prior_sigma_yaw_deg)
        self.graph.add_pose(0, pose)
        self.graph.add_prior(0, pose, cov)
        if self.cfg.odom_scale_sigma is not None:
            self.graph.add_odometry_scale(self.cfg.odom_scale_sigma)
        self._row("prior", 0, 0, pose, cov)
        self._update()

    def step(self, k: int, odometry: np.ndarray, loops: bool, nav: np.ndarray, dt_s: float) -> None:
        """Add keyframe k with the dead-reckoning motion (3,) from k-1, its nav pose (3,)
        and the time since keyframe k-1 [s]."""
        c = self.cfg
        scale = 1.0 + self.graph.scale()
        motion = np.array([odometry[0] / scale[0], odometry[1] / scale[1], odometry[2]])
        guess = se2_compose(self.est[k - 1], motion)
        self.graph.add_pose(k, guess)
        if loops and c.heading_sigma_deg is not None:
            # The navigation yaw is an absolute (AHRS) heading whose error does not grow;
            # odometry factors alone would let it random-walk. x, y stay free.
            cov = np.diag([_FREE_M2, _FREE_M2, np.deg2rad(c.heading_sigma_deg) ** 2])
            if c.heading_bias_walk_deg_sqrt_s is None:
                self.graph.add_prior(k, nav, cov)
                self._row("heading", k, k, nav, cov)
            else:
                self.heading_dt_s += dt_s
                walk = min(  # a bias is an angle: past a half turn it is simply unknown
                    np.deg2rad(c.heading_bias_walk_deg_sqrt_s) * np.sqrt(self.heading_dt_s), np.pi
                )
                if self.bias_key is None:
                    bias = float(wrap_angle(guess[2] - nav[2]))
                else:
                    bias = self.graph.bias(self.bias_key)
                self._biased_heading(k, nav, walk, bias, self.graph)
                self._row("heading", k, k, nav, cov, walk_rad=walk)
                self.heading_dt_s, self.bias_key = 0.0, k
        odo_row = self._row("odometry", k - 1, k, odometry, self._odometry_cov(dt_s))
        if c.odom_scale_sigma is not None:
            self.rows[odo_row]["scaled"] = True
        source = self.points[k]
        target = self._cloud(range(max(0, k - c.ssm_target_frames), k), k - 1)
        reason = "too few points"
        match = None
        if len(source) >= c.min_points and len(target) >= c.min_points:
            half = np.array(
                [c.ssm_window_xy_m, c.ssm_window_xy_m, np.deg2rad(c.ssm_window_yaw_deg)]
            )
            match = self._match(source, target, odometry, half)
            reason = self._check(match, odometry, c.ssm_max_translation_m, c.ssm_max_rotation_deg)
        degenerate = ""
        if match is not None and not reason:
            cov = self._floor(match.covariance, self.icp_cov)
            cov, degenerate, free = self._constrain(match.pose, cov, source, target)
            reason = self._gate(match.pose, odometry, cov, self._step_cov(odometry, dt_s), free)
        if match is not None and not reason:
            self.graph.add_between(k - 1, k, match.pose, cov, huber_k=c.ssm_huber_k)
            self._row(
                "ssm",
                k - 1,
                k,
                match.pose,
                cov,
                overlap=match.overlap,
                rmse=match.rmse_m,
                degenerate=degenerate,
            )
            if c.ssm_replaces_odometry:
                self.rows[odo_row]["status"] = "unused"
                self.edge_covs.append(cov)
            else:
                self._odometry(self.rows[odo_row], self.graph)
                self.edge_covs.append(np.linalg.inv(np.linalg.inv(cov) + self.odom_info))
        else:
            self._odometry(self.rows[odo_row], self.graph)
            z = odometry if match is None else match.pose
            overlap = 0 if match is None else match.overlap
            self._row(
                "ssm",
                k - 1,
                k,
                z,
                self.icp_cov,
                status="rejected",
                reason=reason,
                overlap=overlap,
                degenerate=degenerate,
            )
            self.edge_covs.append(self.chain_odom_cov)
        self._update()
        if loops and k >= c.nssm_min_separation + 1:
            self._loop_closure(k)

    def result(self) -> SlamResult:
        covs = np.array([self.graph.marginal_covariance(k) for k in range(self.graph.size)])
        scale = None if self.cfg.odom_scale_sigma is None else self.graph.scale()
        return SlamResult(self.est.copy(), covs, self.rows, odometry_scale=scale)


def run_slam(
    config: SlamConfig, dr_se2: np.ndarray, points: list[np.ndarray], t_s: np.ndarray
) -> SlamResult:
    """Planar SLAM (mode "slam") or dead reckoning through the same graph ("dead_reckoning").

    Args:
        config: stage config.
        dr_se2: (K, 3) dead-reckoning poses (x_m, y_m, yaw_rad) of the keyframes, world frame.
        points: K arrays (N_k, 2) of horizontal features in base_link.
        t_s: (K,) keyframe times [s] (the heading bias walks with time).
    """
    use_sonar = config.mode == "slam"
    dr_se2 = np.asarray(dr_se2, np.float64)
    front = _FrontEnd(config, points if use_sonar else [np.zeros((0, 2))] * len(points))
    front.start(dr_se2[0])
    for k in range(1, len(dr_se2)):
        dt_s = float(t_s[k] - t_s[k - 1])
        front.step(k, se2_between(dr_se2[k - 1], dr_se2[k]), use_sonar, dr_se2[k], dt_s)
    if use_sonar:
        front.refine_loops()
    result = front.result()
    matched = any(
        r["type"] in ("ssm", "loop") and r["status"] == "accepted" for r in result.factors
    )
    if use_sonar and not matched:
        # Nothing from the sonar: the graph holds only the navigation's own factors, and
        # the dead-reckoned poses are what it says (bit for bit, not re-solved).
        result.poses, result.fell_back = np.array(dr_se2, np.float64), True
        result.odometry_scale = None
    return result
