"""Loop closure of the SLAM front end: NSSM against older keyframes, PCM, re-registration.

Once far enough from the start, each keyframe is matched (non-sequential scan matching)
against the older keyframes whose features it could see (`_footprint_targets`); a loop
enters the graph only as a member of a pairwise consistent set (PCM, `sonarmap.stages.slam.pcm`),
under a Cauchy kernel. After the last keyframe every accepted loop is registered again
from the optimised poses and the whole graph re-solved (`loop_refine_passes`), each
loop's covariance multiplied by the number of loops that share its sonar data
(`loop_shared_window`, `_shared_data_counts`) and by its baseline factor
(`baseline_covariance_factor`); each pass also registers every SSM factor again
(`ssm_refine_target_frames`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from sonarmap.stages.kernels.lazy import lazy
from sonarmap.stages.slam.config import LEGACY_FAN_DEG, SlamConfig
from sonarmap.stages.slam.pcm import chain_covariance, maximum_clique, pairwise_consistency
from sonarmap.stages.slam.pose_graph import (
    PlanarPoseGraph,
    se2_adjoint,
    se2_between,
    se2_inverse,
    se2_log,
    wrap_angle,
)
from sonarmap.stages.slam.scan_matching import (
    MatchResult,
    icp_with_covariance,
    transform_points,
)

spatial = lazy("scipy.spatial")

__all__ = ["LoopCandidate", "LoopClosures", "baseline_covariance_factor", "view_change_deg"]

_RESOLVE_ITERATIONS = 4
"""Extra iSAM2 iterations of a batch re-solve after the loop re-registration."""


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
    keyframes, sigma ~ a + b d with g = a / b (`SlamConfig.loop_baseline_growth_m`;
    docs/decisions/013-loop-covariance-grows-with-baseline.md), because
    the two views of a structure see its leading edges at other ranges and incidences. The
    ICP covariance does not see that (it is about flat in d). The factor only moves weight
    from long loops to short ones; the overall loop weight stays the floor's and the
    sharing's. 1 when `growth_m` is None.
    """
    if growth_m is None:
        return 1.0
    return float(((growth_m + baseline_m) / (growth_m + reference_m)) ** 2)


def view_change_deg(
    source: np.ndarray, target: np.ndarray, pose: np.ndarray, gate_m: float
) -> float:
    """Median angle [deg] between the directions from which the two keyframes see the
    structure they match: each source point registered at `pose` (frame of the target's
    keyframe) and paired within `gate_m`, seen from the origin and from `pose`; 0 unpaired."""
    if len(source) == 0 or len(target) == 0:
        return 0.0
    moved = transform_points(pose, source)
    dist, _ = spatial.cKDTree(target).query(moved, distance_upper_bound=gate_m)
    seen = moved[np.isfinite(dist)]
    if len(seen) == 0:
        return 0.0
    from_t = np.arctan2(seen[:, 1], seen[:, 0])
    from_k = np.arctan2(seen[:, 1] - pose[1], seen[:, 0] - pose[0])
    return float(np.degrees(np.median(np.abs(wrap_angle(from_t - from_k)))))


@dataclass
class LoopCandidate:
    src: int
    dst: int
    match: MatchResult
    covariance: np.ndarray
    row: int
    accepted: bool = False


class LoopClosures:
    """The loop-closure half of the front end (mixed into `sonarmap.stages.slam.frontend._FrontEnd`,
    whose sequential half provides the state below and `_cloud`, `_index`, `_match`, `_check`,
    `_floor`, `_constrain`, `_row` and `_update`)."""

    cfg: SlamConfig
    points: list[np.ndarray]
    reach_m: np.ndarray  # (K,) the farthest point of each keyframe from its origin [m]
    graph: PlanarPoseGraph
    est: np.ndarray
    edge_covs: list[np.ndarray]
    rows: list[dict[str, Any]]
    queue: list[LoopCandidate]
    loop_cov: np.ndarray

    def _footprint_targets(self, k: int, sigma_xy: float, sigma_yaw: float) -> list[int]:
        """Older keyframes whose points keyframe k could see, most points first: the best
        and up to `nssm_fallback_targets` more, each from another stretch of the track."""
        c = self.cfg
        max_range_m = c.nssm_max_range_m + 5 * sigma_xy
        max_heading = np.deg2rad(c.nssm_max_heading_change_deg)
        n_old = max(0, k - c.nssm_min_separation)
        if n_old == 0:
            return []
        # Candidates from a spatial index over the older keyframes' positions: the nearest
        # `nssm_max_candidates` within the reach of any keyframe's points (a mission that
        # keeps revisiting one basin would otherwise bring every older keyframe into view,
        # and the cost per keyframe would grow with the mission); then keyframes none of
        # whose own points can be in view are left out before moving their points (1 m of
        # margin over rounding).
        tree = spatial.cKDTree(self.est[:n_old, :2])
        ball = max_range_m + 1.0 + float(self.reach_m[:n_old].max())
        if c.nssm_max_candidates is None:
            found = tree.query_ball_point(self.est[k, :2], ball)
        else:
            dist, found = tree.query(
                self.est[k, :2], k=min(n_old, c.nssm_max_candidates), distance_upper_bound=ball
            )
            found = np.atleast_1d(found)[np.isfinite(np.atleast_1d(dist))]
        cand = np.sort(np.asarray(found, dtype=np.int64))
        heading = np.abs(wrap_angle(self.est[cand, 2] - self.est[k, 2]))
        distance_m = np.hypot(*(self.est[cand, :2] - self.est[k, :2]).T)
        near = (distance_m - self.reach_m[cand] <= max_range_m + 1.0) & (heading <= max_heading)
        old = [int(i) for i in cand[near] if len(self.points[i])]
        if not old:
            return []
        # each older keyframe's points straight into the frame of k (one pass over them)
        rel = se2_between(self.est[k], self.est[old])
        local = np.concatenate(
            [transform_points(rel[j], self.points[i]) for j, i in enumerate(old)]
        )
        owner = np.concatenate([np.full(len(self.points[i]), i) for i in old])
        r = np.hypot(local[:, 0], local[:, 1])
        bearing = np.abs(np.arctan2(local[:, 1], local[:, 0]))
        visible = (r < max_range_m) & (
            bearing < np.deg2rad(c.nssm_aperture_deg or LEGACY_FAN_DEG) / 2 + 5 * sigma_yaw
        )
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
        cov, degenerate, _ = self._constrain(match.pose, cov, source, target)
        dev = se2_log(se2_between(guess, match.pose))
        if not reason and dev @ np.linalg.solve(rel + cov, dev) > c.nssm_gate_chi2:
            reason = "inconsistent with odometry"
        if not reason and c.loop_max_view_change_deg is not None:
            seen = view_change_deg(source, target, match.pose, c.max_correspondence_m)
            if seen > c.loop_max_view_change_deg:
                reason = "viewpoint change"
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
            degenerate=degenerate,
        )
        if reason:
            return False
        self.queue.append(LoopCandidate(t, k, match, cov, row))
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
                source, target = self._loop_clouds(t, k)
                pose, overlap, rmse, cov = self._reregister(source, target, t, k)
                growth = baseline_covariance_factor(
                    float(np.hypot(pose[0], pose[1])),
                    c.loop_baseline_growth_m,
                    c.loop_reference_baseline_m,
                )
                cov = self._floor(cov, self.loop_cov) * sharing[i] * growth
                cov, degenerate, _ = self._constrain(pose, cov, source, target)
                row.update(z=pose, cov=cov, overlap=overlap, rmse=rmse, degenerate=degenerate)
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
            self._index(target),
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
        gate against more keyframes cuts that error
        (docs/decisions/014-ssm-refinement.md). A match that
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
                cov, degenerate, _ = self._constrain(
                    pose, self._floor(cov, self.icp_cov), self.points[k], target
                )
                row.update(z=pose, cov=cov, overlap=overlap, rmse=rmse, degenerate=degenerate)

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
                loop = row["type"] == "loop"
                graph.add_between(
                    row["key_from"],
                    row["key_to"],
                    row["z"],
                    row["cov"],
                    self.cfg.loop_cauchy_k if loop else None,
                    None if loop else self.cfg.ssm_huber_k,
                )
        graph.update(extra_iterations=_RESOLVE_ITERATIONS)
        self.graph = graph
        self.est = graph.poses()
