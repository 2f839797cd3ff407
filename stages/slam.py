"""The `slam` stage: planar pose-graph SLAM over keyframes (paper Sec. IV.A).

State: one Pose2 (x, y, yaw) per keyframe on GTSAM iSAM2; z, roll and pitch come from the
navigation stream. Factors (the paper's factor graph, Sec. IV.A): a prior on the first
pose; an absolute heading factor per keyframe from the navigation yaw (an AHRS heading,
whose error does not accumulate; our addition); per consecutive pair either sequential scan matching (SSM: ICP of the keyframe's
horizontal features against the previous few keyframes, globally initialised by consensus
maximisation) or, when SSM fails its checks, dead reckoning; and loop closures from
non-sequential scan matching (NSSM) against older keyframes whose footprint could overlap,
admitted only as a pairwise-consistent set (PCM, `stages.pcm`) and then under a Cauchy
kernel (their error is heavy-tailed: a structure seen from another viewpoint returns
from other parts of its surface).

Modes: `slam`, `dead_reckoning` (the navigation poses with their propagated covariance),
`ground_truth` (true poses, to isolate mapping errors as in the paper's simulation study).
Outputs: poses, factors (parquet), trajectory (TUM text), plot (PNG); see `schemas.slam`.
"""

from __future__ import annotations

import io
import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import pyarrow as pa
from pydantic import Field

from schemas.slam import COVARIANCE_COLUMNS, FACTORS_SCHEMA, POSES_SCHEMA
from stages.base import Output, Stage, StageConfig
from stages.pcm import CHI2_99_3DOF, chain_covariance, maximum_clique, pairwise_consistency
from stages.pose_graph import (
    PlanarPoseGraph,
    se2_adjoint,
    se2_between,
    se2_compose,
    se2_inverse,
    se2_log,
    wrap_angle,
)
from stages.scan_matching import (
    MatchResult,
    match_scans,
    polar_to_base,
    transform_points,
    voxel_downsample,
)

__all__ = [
    "STAGE",
    "SlamConfig",
    "SlamResult",
    "keyframe_points",
    "leading_edges",
    "run",
    "run_slam",
]

log = logging.getLogger(__name__)

_TRIU = np.triu_indices(3)
_FREE_M2 = 1e6
"""Variance [m^2] of the position part of a heading-only prior (unconstrained)."""


class SlamConfig(StageConfig):
    """Config of the `slam` stage. Defaults are the authors' (`slam.yaml`, `icp.yaml`)."""

    mode: Literal["slam", "dead_reckoning", "ground_truth"] = "slam"
    prior_sigma_xy_m: float = Field(0.1, gt=0)
    prior_sigma_yaw_deg: float = Field(0.573, gt=0, description="0.01 rad")
    odom_sigma_xy_m: float = Field(0.05, gt=0, description="per keyframe step")
    odom_sigma_yaw_deg: float = Field(0.6, gt=0, description="per keyframe step")
    heading_sigma_deg: float | None = Field(
        0.5,
        gt=0,
        description="mode slam: absolute heading factor per keyframe from the navigation yaw"
        " (AHRS heading: white noise, its bias is a common rotation); None: off",
    )
    ssm_replaces_odometry: bool = Field(
        False, description="authors: SSM replaces odometry; default: both factors are fused"
    )
    icp_sigma_xy_m: float = Field(
        0.03, gt=0, description="floor of an SSM covariance (measured SSM error 0.02-0.05 m)"
    )
    icp_sigma_yaw_deg: float = Field(0.2, gt=0, description="measured SSM error 0.16-0.21 deg")
    covariance_floor: Literal["replace", "scale"] = Field(
        "scale", description="scale keeps the ICP Hessian's x-yaw correlation (lever arm)"
    )
    loop_sigma_xy_m: float = Field(0.1, gt=0, description="floor of a loop's covariance")
    loop_sigma_yaw_deg: float = Field(0.573, gt=0)
    point_resolution_m: float = Field(0.25, gt=0, description="voxel size of keyframe clouds")
    leading_edge_only: bool = Field(True, description="first cell of each run along a beam")
    point_noise_m: float = Field(0.5, gt=0, description="grid dilation and overlap radius")
    grid_resolution_m: float = Field(0.25, gt=0, description="consensus grid cell")
    max_correspondence_m: float = Field(1.0, gt=0, description="ICP correspondence gate")
    search_max_points: int = Field(150, ge=10, description="source points scored in the search")
    icp_effective_samples: float | None = Field(
        4.0, gt=0, description="independent residuals assumed in the ICP covariance"
    )
    search_tie_fraction: float = Field(
        0.9, gt=0, le=1, description="consensus within this of the best: nearest the guess wins"
    )
    icp_max_iterations: int = Field(40, ge=1)
    min_points: int = Field(30, ge=3, description="points needed in source and target")
    min_overlap_points: int = Field(30, ge=3, description="overlapping points to accept")
    ssm_target_frames: int = Field(3, ge=1)
    ssm_window_xy_m: float = Field(1.0, gt=0, description="global search half-width")
    ssm_window_yaw_deg: float = Field(5.73, gt=0)
    ssm_max_translation_m: float = Field(2.0, gt=0, description="max deviation from odometry")
    ssm_max_rotation_deg: float = Field(30.0, gt=0)
    nssm_min_separation: int = Field(8, ge=1, description="keyframes between loop ends")
    nssm_source_frames: int = Field(5, ge=1)
    nssm_target_frames: int = Field(5, ge=1, description="target frames around the best one")
    nssm_min_frame_points: int = Field(10, ge=1)
    nssm_max_range_m: float = Field(30.0, gt=0)
    nssm_max_heading_change_deg: float = Field(
        180.0, gt=0, description="loop targets seen with a heading within this of the current"
    )
    nssm_aperture_deg: float = Field(130.0, gt=0)
    nssm_window_xy_m: tuple[float, float] = (1.0, 5.0)
    nssm_window_yaw_deg: tuple[float, float] = (5.73, 20.0)
    nssm_max_translation_m: float = Field(10.0, gt=0)
    nssm_max_rotation_deg: float = Field(60.0, gt=0)
    nssm_gate_chi2: float = Field(
        16.27, gt=0, description="chi2(0.999, 3) gate of a loop against the odometry chain"
    )
    loop_cauchy_k: float | None = Field(
        1.0,
        gt=0,
        description="Cauchy kernel scale on loop factors (whitened error): loop errors are"
        " heavy-tailed (viewpoint-dependent sonar returns); None: Gaussian",
    )
    pcm_queue_keyframes: int = Field(5, ge=0)
    pcm_min_clique: int = Field(2, ge=1)
    pcm_chi2_threshold: float = Field(CHI2_99_3DOF, gt=0, description="chi2(0.99, 3)")
    plot_max_points: int = Field(30000, ge=0)


def _diag_cov(sigma_xy_m: float, sigma_yaw_deg: float) -> np.ndarray:
    return np.diag([sigma_xy_m**2, sigma_xy_m**2, np.deg2rad(sigma_yaw_deg) ** 2])


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
        self.odom_cov = _diag_cov(config.odom_sigma_xy_m, config.odom_sigma_yaw_deg)
        self.odom_info = np.linalg.inv(self.odom_cov)
        self.loop_cov = _diag_cov(config.loop_sigma_xy_m, config.loop_sigma_yaw_deg)

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
        self._row("prior", 0, 0, pose, cov)
        self._update()

    def step(self, k: int, odometry: np.ndarray, loops: bool, nav: np.ndarray) -> None:
        """Add keyframe k with the dead-reckoning motion (3,) from k-1 and its nav pose (3,)."""
        c = self.cfg
        self.graph.add_pose(k, se2_compose(self.est[k - 1], odometry))
        if loops and c.heading_sigma_deg is not None:
            # The navigation yaw is an absolute (AHRS) heading whose error does not grow;
            # odometry factors alone would let it random-walk. x, y stay free.
            cov = np.diag([_FREE_M2, _FREE_M2, np.deg2rad(c.heading_sigma_deg) ** 2])
            self.graph.add_prior(k, nav, cov)
            self._row("heading", k, k, nav, cov)
        odo_row = self._row("odometry", k - 1, k, odometry, self.odom_cov)
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
                self.graph.add_between(k - 1, k, odometry, self.odom_cov)
                self.edge_covs.append(np.linalg.inv(np.linalg.inv(cov) + self.odom_info))
        else:
            self.graph.add_between(k - 1, k, odometry, self.odom_cov)
            z = odometry if match is None else match.pose
            overlap = 0 if match is None else match.overlap
            self._row(
                "ssm", k - 1, k, z, self.icp_cov, status="rejected", reason=reason, overlap=overlap
            )
            self.edge_covs.append(self.odom_cov)
        self._update()
        if loops and k >= c.nssm_min_separation + 1:
            self._loop_closure(k)

    def _footprint_target(self, k: int, sigma_xy: float, sigma_yaw: float) -> int | None:
        c = self.cfg
        old = [i for i in range(k - c.nssm_min_separation) if len(self.points[i])]
        if not old:
            return None
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
        best = int(np.argmax(counts))
        return best if counts[best] > c.nssm_min_frame_points else None

    def _relative_covariance(self, t: int, k: int) -> np.ndarray:
        """(3, 3) covariance of pose k in the frame of t along the chain (frame of k)."""
        chain = chain_covariance(self.est[: k + 1], np.array(self.edge_covs[:k]))
        ad = se2_adjoint(se2_inverse(self.est[k]))
        return ad @ (chain[k] - chain[t]) @ ad.T

    def _loop_closure(self, k: int) -> None:
        c = self.cfg
        rel = self._relative_covariance(0, k)
        t = self._footprint_target(
            k, float(np.sqrt(np.linalg.eigvalsh(rel[:2, :2])[-1])), float(np.sqrt(rel[2, 2]))
        )
        if t is None:
            return
        source = self._cloud(range(max(0, k - c.nssm_source_frames + 1), k + 1), k)
        half_t = c.nssm_target_frames // 2
        limit = k - c.nssm_min_separation
        target = self._cloud(range(max(0, t - half_t), min(limit, t + half_t + 1)), t)
        if len(source) < c.min_points or len(target) < c.min_points:
            return
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
            return
        self.queue.append(_Candidate(t, k, match, cov, row))
        self._pcm(k)

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

    def result(self) -> SlamResult:
        covs = np.array([self.graph.marginal_covariance(k) for k in range(self.graph.size)])
        return SlamResult(self.est.copy(), covs, self.rows)


def leading_edges(keyframe_id: np.ndarray, beam: np.ndarray, range_bin: np.ndarray) -> np.ndarray:
    """(N,) bool: the nearest cell of each run of consecutive detections along a beam.

    A horizontal sonar smears a vertical surface at horizontal distance d from d out to
    d / cos(aperture / 2) (the unresolved elevation), so only the first cell of a run is
    where the surface is; it is also the part that does not change with the viewpoint.

    Args:
        keyframe_id, beam, range_bin: (N,) int cells of horizontal features.
    """
    order = np.lexsort((range_bin, beam, keyframe_id))
    k, b, r = keyframe_id[order], beam[order], range_bin[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = (k[1:] != k[:-1]) | (b[1:] != b[:-1]) | (r[1:] != r[:-1] + 1)
    out = np.zeros(len(order), dtype=bool)
    out[order] = first
    return out


def keyframe_points(
    keyframe_ids: np.ndarray,
    features: pa.Table,
    T_base_sonar: np.ndarray,
    voxel_m: float,
    leading_edge_only: bool = True,
) -> list[np.ndarray]:
    """Horizontal features per keyframe as (N_k, 2) base_link points at elevation 0.

    Args:
        keyframe_ids: (K,) ids in keyframe order.
        features: the features table (keyframe_id, sonar, range_bin, beam, range_m,
            angle_rad, ...).
        T_base_sonar: (4, 4) horizontal sonar mounting.
        voxel_m: voxel size of the per-keyframe downsampling.
        leading_edge_only: keep only `leading_edges` cells.
    """
    sonar = features.column("sonar").to_numpy(zero_copy_only=False)
    keep = sonar == "horizontal"
    kf = features.column("keyframe_id").to_numpy()[keep]
    range_m = features.column("range_m").to_numpy()[keep]
    angle = features.column("angle_rad").to_numpy()[keep]
    if leading_edge_only:
        edge = leading_edges(
            kf,
            features.column("beam").to_numpy()[keep],
            features.column("range_bin").to_numpy()[keep],
        )
        kf, range_m, angle = kf[edge], range_m[edge], angle[edge]
    pts = polar_to_base(range_m, angle, T_base_sonar)
    order = np.argsort(kf, kind="stable")
    kf, pts = kf[order], pts[order]
    lo = np.searchsorted(kf, keyframe_ids, side="left")
    hi = np.searchsorted(kf, keyframe_ids, side="right")
    return [voxel_downsample(pts[a:b], voxel_m) for a, b in zip(lo, hi, strict=True)]


def run_slam(config: SlamConfig, dr_se2: np.ndarray, points: list[np.ndarray]) -> SlamResult:
    """Planar SLAM (mode "slam") or dead reckoning through the same graph ("dead_reckoning").

    Args:
        config: stage config.
        dr_se2: (K, 3) dead-reckoning poses (x_m, y_m, yaw_rad) of the keyframes, world frame.
        points: K arrays (N_k, 2) of horizontal features in base_link.
    """
    use_sonar = config.mode == "slam"
    front = _FrontEnd(config, points if use_sonar else [np.zeros((0, 2))] * len(points))
    front.start(dr_se2[0])
    for k in range(1, len(dr_se2)):
        front.step(k, se2_between(dr_se2[k - 1], dr_se2[k]), use_sonar, dr_se2[k])
    return front.result()


def _pose_columns(keyframes: pa.Table, prefix: str) -> np.ndarray:
    names = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
    cols = [keyframes.column(prefix + n) for n in names]
    if any(col.null_count for col in cols):
        raise ValueError(f"keyframes: column {prefix}x_m.. has nulls (no such poses in the data)")
    return np.stack([col.to_numpy() for col in cols], axis=1).astype(np.float64)


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
    roll, pitch, yaw = pose6[:, 3] / 2, pose6[:, 4] / 2, pose6[:, 5] / 2
    cr, sr, cp, sp, cy, sy = (
        np.cos(roll),
        np.sin(roll),
        np.cos(pitch),
        np.sin(pitch),
        np.cos(yaw),
        np.sin(yaw),
    )
    q = np.stack(
        [
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ],
        axis=1,
    )
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

    fig = Figure(figsize=(7, 7), dpi=110)
    ax = fig.add_subplot()
    world = [transform_points(p, pts) for p, pts in zip(pose_se2, points, strict=True) if len(pts)]
    if world and max_points > 0:
        cloud = np.concatenate(world)
        cloud = cloud[:: max(1, len(cloud) // max_points)]
        ax.plot(cloud[:, 0], cloud[:, 1], ",", c="0.6", label="features")
    if gt_se2 is not None:
        ax.plot(gt_se2[:, 0], gt_se2[:, 1], "-", c="tab:green", lw=1.2, label="ground truth")
    ax.plot(dr_se2[:, 0], dr_se2[:, 1], "--", c="tab:orange", lw=1.0, label="dead reckoning")
    ax.plot(pose_se2[:, 0], pose_se2[:, 1], "-", c="tab:blue", lw=1.2, label="estimate")
    for n, (a, b) in enumerate(loops):
        ax.plot(*pose_se2[[a, b], :2].T, "-", c="tab:red", lw=0.8, label="loop" if n == 0 else None)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


def run(config: SlamConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    """Stage entry point: keyframes, sensors, features -> poses, factors, trajectory, plot."""
    keyframes: pa.Table = inputs["keyframes.keyframes"]
    if keyframes.num_rows == 0:
        raise ValueError("slam: the keyframes table is empty")
    ids = keyframes.column("keyframe_id").to_numpy().astype(np.int64)
    t_ns = keyframes.column("t_ns").to_numpy().astype(np.int64)
    dr = _pose_columns(keyframes, "")
    gt = None if keyframes.column("gt_x_m").null_count else _pose_columns(keyframes, "gt_")
    T_base_sonar = np.asarray(inputs["keyframes.sensors"]["horizontal"]["T_base_sonar"], float)
    points = keyframe_points(
        ids,
        inputs["features.features"],
        T_base_sonar,
        config.point_resolution_m,
        config.leading_edge_only,
    )
    dr_se2 = dr[:, [0, 1, 5]]
    if config.mode == "ground_truth":
        if gt is None:
            raise ValueError("slam: mode ground_truth, but the keyframes carry no ground truth")
        pose6, cov, rows = gt, np.zeros((len(ids), 3, 3)), []
    else:
        result = run_slam(config, dr_se2, points)
        pose6 = dr.copy()
        pose6[:, [0, 1, 5]] = result.poses
        pose6[:, 5] = wrap_angle(pose6[:, 5])
        cov, rows = result.covariances, result.factors
    loops = np.array(
        [
            (r["key_from"], r["key_to"])
            for r in rows
            if r["type"] == "loop" and r["status"] == "accepted"
        ],
        dtype=np.int64,
    ).reshape(-1, 2)
    n_loops = len(loops)
    log.info("slam (%s): %d keyframes, %d loop closures", config.mode, len(ids), n_loops)
    return {
        "poses": poses_table(ids, t_ns, pose6, cov),
        "factors": factors_table(rows, ids),
        "trajectory": tum_text(t_ns, pose6),
        "plot": plot_png(
            pose6[:, [0, 1, 5]],
            dr_se2,
            None if gt is None else gt[:, [0, 1, 5]],
            points,
            loops,
            config.plot_max_points,
            f"slam ({config.mode}): {len(ids)} keyframes, {n_loops} loop closures",
        ),
    }


STAGE = Stage(
    name="slam",
    version=2,
    config=SlamConfig,
    inputs=("keyframes.keyframes", "keyframes.sensors", "features.features"),
    outputs=(
        Output("poses", "parquet", "poses.parquet", schema=POSES_SCHEMA),
        Output("factors", "parquet", "factors.parquet", schema=FACTORS_SCHEMA),
        Output("trajectory", "bytes", "trajectory.tum"),
        Output("plot", "bytes", "trajectory.png"),
    ),
    run=run,
    description="planar pose-graph SLAM (iSAM2): scan matching, loop closures with PCM",
)
