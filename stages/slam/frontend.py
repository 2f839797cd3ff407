"""Incremental SLAM front end: SSM, NSSM and PCM over keyframes on one iSAM2 graph.

Per keyframe (paper Sec. IV.A): an odometry factor (through the mission's odometry scale
error, a state: `PlanarPoseGraph.add_scaled_odometry`), an absolute heading factor (mode
slam; through a random-walk bias state, `PlanarPoseGraph.add_biased_heading`),
sequential scan matching against the previous few keyframes and, once far enough from
the start, non-sequential scan matching (loop closure) against the older keyframe
whose features could overlap; a loop enters the graph only as a member of a pairwise
consistent set (PCM, `stages.slam.pcm`), under a Cauchy kernel. After the last keyframe every
accepted loop is registered again from the optimised poses and the whole graph re-solved
(`loop_refine_passes`), each loop's covariance multiplied by the number of loops that share
its sonar data (`loop_shared_window`); each pass also registers every SSM factor again
(`ssm_refine_target_frames`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stages.slam.config import SlamConfig
from stages.slam.pcm import chain_covariance, maximum_clique, pairwise_consistency
from stages.slam.pose_graph import (
    PlanarPoseGraph,
    se2_adjoint,
    se2_between,
    se2_compose,
    se2_inverse,
    se2_log,
    wrap_angle,
)
from stages.slam.scan_matching import (
    MatchResult,
    icp_with_covariance,
    match_scans,
    transform_points,
    voxel_downsample,
)

__all__ = ["SlamResult", "baseline_covariance_factor", "run_slam"]

_FREE_M2 = 1e6
"""Variance [m^2] of the position part of a heading-only prior (unconstrained)."""

_RESOLVE_ITERATIONS = 4
"""Extra iSAM2 iterations of a batch re-solve after the loop re-registration."""


def _diag_cov(sigma_xy_m: float, sigma_yaw_deg: float) -> np.ndarray:
    return np.diag([sigma_xy_m**2, sigma_xy_m**2, np.deg2rad(sigma_yaw_deg) ** 2])


def _shared_data_counts(src: np.ndarray, dst: np.ndarray, window: int) -> np.ndarray:
    """(L,) for each loop src -> dst, the number of loops (itself included) whose ends are
    both within `window` keyframes of its own; 1 everywhere when window is 0."""
    if window == 0:
        return np.ones(len(src))
    near = (np.abs(src[:, None] - src[None]) <= window) & (
        np.abs(dst[:, None] - dst[None]) <= window
    )
    return near.sum(axis=1).astype(np.float64)


def baseline_covariance_factor(
    baseline_m: float, growth_m: float | None, reference_m: float
) -> float:
    """((g + d) / (g + d_ref))^2: a loop's covariance relative to one of baseline d_ref.

    The error of a loop measurement grows about linearly with the baseline d between its
    keyframes, sigma ~ a + b d with g = a / b (`SlamConfig.loop_baseline_growth_m`; on
    simulated marina missions RMS 0.035 m under 5 m to 0.23-0.33 m at 30-40 m), because
    the two views of a structure see its leading edges at other ranges and incidences. The
    ICP covariance does not see that (it is about flat in d). The factor only moves weight
    from long loops to short ones; the overall loop weight stays the floor's and the
    sharing's. 1 when `growth_m` is None.
    """
    if growth_m is None:
        return 1.0
    return float(((growth_m + baseline_m) / (growth_m + reference_m)) ** 2)


@dataclass
class _Candidate:
    src: int
    dst: int
    match: MatchResult
    covariance: np.ndarray
    row: int
    accepted: bool = False


@dataclass
class SlamResult:
    """Poses (K, 3) (x_m, y_m, yaw_rad), covariances (K, 3, 3), factor rows (dicts)."""

    poses: np.ndarray
    covariances: np.ndarray
    factors: list[dict[str, Any]] = field(default_factory=list)


class _FrontEnd:
    """Incremental SSM + NSSM + PCM over keyframes, feeding one `PlanarPoseGraph`."""

    def __init__(self, config: SlamConfig, points: list[np.ndarray]) -> None:
        self.cfg = config
        self.points = points
        self.graph = PlanarPoseGraph()
        self.est = np.zeros((0, 3))
        self.edge_covs: list[np.ndarray] = []
        self.rows: list[dict[str, Any]] = []
        self.queue: list[_Candidate] = []
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
        return _diag_cov(c.odom_sigma_xy_m_sqrt_s * np.sqrt(max(dt_s, 0.01)), c.odom_sigma_yaw_deg)

    def _odometry(self, row: dict[str, Any], graph: PlanarPoseGraph) -> None:
        a, b, z, cov = row["key_from"], row["key_to"], row["z"], row["cov"]
        if row.get("scaled"):
            graph.add_scaled_odometry(a, b, z, cov)
        else:
            graph.add_between(a, b, z, cov)

    def _row(self, kind: str, a: int, b: int, z: np.ndarray, cov: np.ndarray, **kw: Any) -> int:
        row = {"type": kind, "key_from": a, "key_to": b, "z": np.asarray(z, float), "cov": cov}
        row.update({"status": "accepted", "reason": "", "overlap": 0, "rmse": None, **kw})
        self.rows.append(row)
        return len(self.rows) - 1

    def _update(self, extra_iterations: int = 0) -> None:
        self.graph.update(extra_iterations)
        self.est = self.graph.poses()

    def _cloud(self, frames: range, anchor: int) -> np.ndarray:
        parts = [
            transform_points(se2_between(self.est[anchor], self.est[j]), self.points[j])
            for j in frames
            if len(self.points[j])
        ]
        if not parts:
            return np.zeros((0, 2))
        return voxel_downsample(np.concatenate(parts), self.cfg.point_resolution_m)

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
            target,
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
                walk = np.deg2rad(c.heading_bias_walk_deg_sqrt_s) * np.sqrt(self.heading_dt_s)
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
        if match is not None and not reason:
            cov = self._floor(match.covariance, self.icp_cov)
            self.graph.add_between(k - 1, k, match.pose, cov)
            self._row("ssm", k - 1, k, match.pose, cov, overlap=match.overlap, rmse=match.rmse_m)
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
                "ssm", k - 1, k, z, self.icp_cov, status="rejected", reason=reason, overlap=overlap
            )
            self.edge_covs.append(self.chain_odom_cov)
        self._update()
        if loops and k >= c.nssm_min_separation + 1:
            self._loop_closure(k)

    def _footprint_targets(self, k: int, sigma_xy: float, sigma_yaw: float) -> list[int]:
        """Older keyframes whose points keyframe k could see, most points first: the best
        and up to `nssm_fallback_targets` more, each from another stretch of the track."""
        c = self.cfg
        old = [i for i in range(k - c.nssm_min_separation) if len(self.points[i])]
        if not old:
            return []
        world = np.concatenate([transform_points(self.est[i], self.points[i]) for i in old])
        owner = np.concatenate([np.full(len(self.points[i]), i) for i in old])
        local = transform_points(se2_between(self.est[k], np.zeros(3)), world)
        r = np.hypot(local[:, 0], local[:, 1])
        bearing = np.abs(np.arctan2(local[:, 1], local[:, 0]))
        visible = (r < c.nssm_max_range_m + 5 * sigma_xy) & (
            bearing < np.deg2rad(c.nssm_aperture_deg) / 2 + 5 * sigma_yaw
        )
        heading = np.abs(wrap_angle(self.est[owner, 2] - self.est[k, 2]))
        visible &= heading <= np.deg2rad(c.nssm_max_heading_change_deg)
        counts = np.bincount(owner[visible], minlength=k)
        chosen: list[int] = []
        for t in np.argsort(-counts, kind="stable"):
            if counts[t] <= c.nssm_min_frame_points or len(chosen) > c.nssm_fallback_targets:
                break
            if all(abs(int(t) - u) > c.nssm_target_frames for u in chosen):
                chosen.append(int(t))
        return chosen

    def _relative_covariance(self, t: int, k: int) -> np.ndarray:
        """(3, 3) covariance of pose k in the frame of t along the chain (frame of k)."""
        chain = chain_covariance(self.est[: k + 1], np.array(self.edge_covs[:k]))
        ad = se2_adjoint(se2_inverse(self.est[k]))
        return ad @ (chain[k] - chain[t]) @ ad.T

    def _loop_clouds(self, t: int, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Source cloud (the last frames up to k, frame of k) and target cloud (frames
        around t, older than k - nssm_min_separation, frame of t) of a loop t -> k."""
        c = self.cfg
        source = self._cloud(range(max(0, k - c.nssm_source_frames + 1), k + 1), k)
        half_t = c.nssm_target_frames // 2
        limit = k - c.nssm_min_separation
        target = self._cloud(range(max(0, t - half_t), min(limit, t + half_t + 1)), t)
        return source, target

    def _loop_closure(self, k: int) -> None:
        rel = self._relative_covariance(0, k)
        targets = self._footprint_targets(
            k, float(np.sqrt(np.linalg.eigvalsh(rel[:2, :2])[-1])), float(np.sqrt(rel[2, 2]))
        )
        for t in targets:
            if self._try_loop(t, k):
                return

    def _try_loop(self, t: int, k: int) -> bool:
        """Match keyframe k against the frames around t; queue the loop if it passes."""
        c = self.cfg
        source, target = self._loop_clouds(t, k)
        if len(source) < c.min_points or len(target) < c.min_points:
            return False
        rel = self._relative_covariance(t, k)
        xy = np.clip(5 * np.sqrt(np.linalg.eigvalsh(rel[:2, :2])[-1]), *c.nssm_window_xy_m)
        yaw = np.clip(5 * np.sqrt(rel[2, 2]), *np.deg2rad(c.nssm_window_yaw_deg))
        guess = se2_between(self.est[t], self.est[k])
        match = self._match(source, target, guess, np.array([xy, xy, yaw]))
        reason = self._check(match, guess, c.nssm_max_translation_m, c.nssm_max_rotation_deg)
        cov = self._floor(match.covariance, self.loop_cov)
        dev = se2_log(se2_between(guess, match.pose))
        if not reason and dev @ np.linalg.solve(rel + cov, dev) > c.nssm_gate_chi2:
            reason = "inconsistent with odometry"
        row = self._row(
            "loop",
            t,
            k,
            match.pose,
            cov,
            overlap=match.overlap,
            rmse=match.rmse_m,
            status="rejected",
            reason=reason or "pcm: not in a consistent set",
        )
        if reason:
            return False
        self.queue.append(_Candidate(t, k, match, cov, row))
        self._pcm(k)
        return True

    def _pcm(self, k: int) -> None:
        c = self.cfg
        self.queue = [q for q in self.queue if q.dst >= k - c.pcm_queue_keyframes]
        src = np.array([q.src for q in self.queue])
        dst = np.array([q.dst for q in self.queue])
        z = np.array([q.match.pose for q in self.queue])
        cov = np.array([q.covariance for q in self.queue])
        chain = chain_covariance(self.est, np.array(self.edge_covs))
        adjacency = pairwise_consistency(self.est, chain, src, dst, z, cov, c.pcm_chi2_threshold)
        clique = maximum_clique(adjacency)
        if len(clique) < c.pcm_min_clique:
            return
        added = False
        for i in clique:
            q = self.queue[int(i)]
            if not q.accepted:
                q.accepted, added = True, True
                self.graph.add_between(q.src, q.dst, q.match.pose, q.covariance, c.loop_cauchy_k)
                self.rows[q.row].update(status="accepted", reason="")
        if added:
            self._update(extra_iterations=2)

    def refine_loops(self) -> None:
        """Re-register the accepted loops from the optimised poses, then re-solve in batch.

        During the incremental run a loop is matched from the odometry-chain guess, through a
        global search, with clouds assembled from drifted poses. Once every loop is in,
        the estimate is good to a few centimetres: ICP alone, with a tight correspondence
        gate, from the current relative pose, with clouds rebuilt from the current poses,
        pairs fewer points on the wrong side of a structure. Each pass replaces the loops'
        measurements and covariances, and the SSM factors' (`_refine_ssm`), then re-solves
        the whole graph from the current estimate (which also finishes the relinearisation
        iSAM2 leaves pending). A mission without loops still gets the SSM passes.

        A loop's covariance is its ICP covariance (floored), times the number of loops that
        share its sonar data, times `baseline_covariance_factor`: the farther apart its two
        keyframes, the more their views of a structure differ, and the less alike the
        returns they register.
        """
        c = self.cfg
        loops = [r for r in self.rows if r["type"] == "loop" and r["status"] == "accepted"]
        if not loops and not c.ssm_refine_target_frames:
            return
        sharing = _shared_data_counts(
            np.array([r["key_from"] for r in loops]),
            np.array([r["key_to"] for r in loops]),
            c.loop_shared_window,
        )
        for _ in range(c.loop_refine_passes):
            for i, row in enumerate(loops):
                t, k = row["key_from"], row["key_to"]
                pose, overlap, rmse, cov = self._reregister(*self._loop_clouds(t, k), t, k)
                growth = baseline_covariance_factor(
                    float(np.hypot(pose[0], pose[1])),
                    c.loop_baseline_growth_m,
                    c.loop_reference_baseline_m,
                )
                cov = self._floor(cov, self.loop_cov) * sharing[i] * growth
                row.update(z=pose, cov=cov, overlap=overlap, rmse=rmse)
            if c.ssm_refine_target_frames:
                self._refine_ssm(c.ssm_refine_target_frames)
            self._resolve()

    def _reregister(
        self, source: np.ndarray, target: np.ndarray, a: int, k: int
    ) -> tuple[np.ndarray, int, float, np.ndarray]:
        """ICP of keyframe k's source cloud on keyframe a's target cloud from the current
        relative pose, with the re-registration's tight gate: (pose, overlap, rmse, cov)."""
        c = self.cfg
        return icp_with_covariance(
            source,
            target,
            se2_between(self.est[a], self.est[k]),
            c.loop_refine_correspondence_m,
            c.icp_max_iterations,
            c.point_noise_m,
            c.icp_effective_samples,
        )

    def _refine_ssm(self, frames: int) -> None:
        """Re-register every accepted SSM factor from the current poses (ICP only, the loop
        re-registration's gate) against the `frames` keyframes before it.

        The incremental SSM starts from a global search with a wide correspondence gate,
        against three keyframes: with CFAR features (clutter, missed returns) its lateral
        error is several times the odometry's. From the optimised poses, ICP with the tight
        gate against more keyframes cuts that error by a third on short marina missions
        and by half on the long CFAR seed 3 (`benchmarks/bench_slam.py`). A match that
        loses its overlap keeps its first measurement.
        """
        c = self.cfg
        for row in self.rows:
            if row["type"] != "ssm" or row["status"] != "accepted":
                continue
            a, k = row["key_from"], row["key_to"]
            target = self._cloud(range(max(0, k - frames), k), a)
            pose, overlap, rmse, cov = self._reregister(self.points[k], target, a, k)
            if overlap >= c.min_overlap_points:
                row.update(z=pose, cov=self._floor(cov, self.icp_cov), overlap=overlap, rmse=rmse)

    def _resolve(self) -> None:
        """Rebuild the graph from the accepted factor rows and solve it from the estimate."""
        graph = PlanarPoseGraph()
        for i, pose in enumerate(self.est):
            graph.add_pose(i, pose)
        if self.cfg.odom_scale_sigma is not None:
            graph.add_odometry_scale(self.cfg.odom_scale_sigma, self.graph.scale())
        for row in self.rows:
            if row["status"] != "accepted":
                continue
            if row["type"] == "heading" and "walk_rad" in row:
                k = row["key_to"]
                self._biased_heading(k, row["z"], row["walk_rad"], self.graph.bias(k), graph)
            elif row["type"] in ("prior", "heading"):
                graph.add_prior(row["key_to"], row["z"], row["cov"])
            elif row["type"] == "odometry":
                self._odometry(row, graph)
            else:
                kernel = self.cfg.loop_cauchy_k if row["type"] == "loop" else None
                graph.add_between(row["key_from"], row["key_to"], row["z"], row["cov"], kernel)
        graph.update(extra_iterations=_RESOLVE_ITERATIONS)
        self.graph = graph
        self.est = graph.poses()

    def result(self) -> SlamResult:
        covs = np.array([self.graph.marginal_covariance(k) for k in range(self.graph.size)])
        return SlamResult(self.est.copy(), covs, self.rows)


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
    front = _FrontEnd(config, points if use_sonar else [np.zeros((0, 2))] * len(points))
    front.start(dr_se2[0])
    for k in range(1, len(dr_se2)):
        dt_s = float(t_s[k] - t_s[k - 1])
        front.step(k, se2_between(dr_se2[k - 1], dr_se2[k]), use_sonar, dr_se2[k], dt_s)
    if use_sonar:
        front.refine_loops()
    return front.result()
