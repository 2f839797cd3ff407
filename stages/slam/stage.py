"""The `slam` stage: planar pose-graph SLAM over keyframes (paper Sec. IV.A).

State: one Pose2 (x, y, yaw) per keyframe on GTSAM iSAM2; z, roll and pitch come from the
navigation stream. Factors (the paper's factor graph, Sec. IV.A): a prior on the first
pose; an absolute heading factor per keyframe from the navigation yaw (an AHRS heading,
whose error does not accumulate; our addition), measured through a heading-bias state per
keyframe that follows a random walk (`heading_bias_walk_deg_sqrt_s`; version 4), so loops
can correct the slowly wandering part of the compass error; per consecutive pair dead
reckoning, read through a per-mission odometry scale error that is a state of its own
(`odom_scale_sigma`, a DVL's scale error; version 6) so that the odometry's white noise
can be the sensor's real one, and, when it passes its checks, sequential scan matching
(SSM: ICP of the keyframe's horizontal features against the previous few keyframes,
globally initialised by consensus maximisation); and loop closures from non-sequential scan matching (NSSM)
against the older keyframe whose footprint overlaps most (and, when that match fails its
checks, the next best from another stretch of the track: `nssm_fallback_targets`, version
5), admitted only as a pairwise-consistent set (PCM, `sonarmap.stages.slam.pcm`) and then under a Cauchy
kernel (their error is heavy-tailed: a structure seen from another viewpoint returns from
other parts of its surface). Once all keyframes are in, every accepted loop is registered
again from the optimised poses (ICP only, tight gate) and the graph re-solved in batch
(`SlamConfig.loop_refine_passes`; version 3); there a cluster of loops that share their
sonar data counts about once (`loop_shared_window`; version 6), and every SSM factor is
registered again too, against more keyframes (`ssm_refine_target_frames`; version 7);
a loop's covariance there also grows with its baseline, as its measured error does
(`loop_baseline_growth_m`; version 8). Every scan match's factor is made free along the
directions of SE(2) its scans leave unconstrained (a straight wall's direction: the
point-to-line information against one step of odometry, `sonarmap.stages.slam.degeneracy`),
and a sequential match must agree with its step's odometry within a chi-square gate
(Mahalanobis, under both covariances) and enters under a Huber kernel (version 11).
Each keyframe's points are thinned on the voxel grid and then outlier-filtered (the
authors' radius filter: `sonarmap.stages.slam.thinning`), so scan matching's cost is
bounded by the area the sonar sees, not by the number of detections (version 12). Before
that, leading edges with too few other detections around them in the image's own cells
are dropped as lone false alarms (`sonarmap.stages.slam.thinning.cell_inliers`), and loop
targets come from a k-d tree over the keyframe positions (version 13). Opt-in
(`degeneracy_tilt_deg`), a degenerate match's factor is also loose across its free
direction by its motion along it times the tangent of a wall's possible apparent tilt.

Modes: `slam`, `dead_reckoning` (the navigation poses with their propagated covariance),
`ground_truth` (true poses, to isolate mapping errors as in the paper's simulation study).
Outputs: poses, factors (parquet), trajectory (TUM text), plot points (the features
registered with the estimate, thinned: what `trajectory.png` of the `figures` stage draws;
version 10), summary (JSON: matches found degenerate, SLAM against the drift the
navigation's noise model predicts, warnings; `sonarmap.stages.slam.health`, version 11);
see `sonarmap.schemas.slam` and `sonarmap.schemas.figures`. When no scan match is
accepted, the poses are dead reckoning's.

The front end is `sonarmap.stages.slam.frontend`, the config `sonarmap.stages.slam.config`, the keyframe
point clouds `sonarmap.stages.slam.points`, the output files `sonarmap.stages.slam.outputs`.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.schemas.sensors import Sensors
from sonarmap.stages.base import Input, StageInputError, StageSettingsError
from sonarmap.stages.slam import STAGE
from sonarmap.stages.slam.config import SlamConfig, with_sensor_fan
from sonarmap.stages.slam.frontend import SlamResult, run_slam
from sonarmap.stages.slam.health import slam_summary
from sonarmap.stages.slam.outputs import factors_table, plot_points, poses_table, tum_text
from sonarmap.stages.slam.points import counted_keyframe_points, keyframe_points, leading_edges
from sonarmap.stages.slam.pose_graph import wrap_angle

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


def _pose_columns(keyframes: pa.Table, prefix: str) -> np.ndarray:
    names = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
    cols = [keyframes.column(prefix + n) for n in names]
    if any(col.null_count for col in cols):
        raise StageInputError(
            Input("keyframes", "keyframes"),
            f"column {prefix}x_m.. has nulls (no such poses in the data)",
        )
    return np.stack([col.to_numpy() for col in cols], axis=1).astype(np.float64)


def run(config: SlamConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    """Stage entry point: keyframes, sensors, features -> poses, factors, trajectory, plot points."""
    config = with_sensor_fan(config, inputs["keyframes.sensors"])  # the fan from one place
    keyframes: pa.Table = inputs["keyframes.keyframes"]
    if keyframes.num_rows == 0:
        raise StageInputError(Input("keyframes", "keyframes"), "the keyframes table is empty")
    ids = keyframes.column("keyframe_id").to_numpy().astype(np.int64)
    t_ns = keyframes.column("t_ns").to_numpy().astype(np.int64)
    dr = _pose_columns(keyframes, "")
    gt = None if keyframes.column("gt_x_m").null_count else _pose_columns(keyframes, "gt_")
    T_base_sonar = Sensors.of(inputs["keyframes.sensors"]).horizontal.T_base_sonar
    points, point_counts = counted_keyframe_points(
        ids,
        inputs["features.features"],
        T_base_sonar,
        config.point_resolution_m,
        config.leading_edge_only,
        config.outlier_radius_m,
        config.outlier_min_neighbours,
        config.max_points_per_keyframe,
        None if config.lone_cell_beams is None else (config.lone_cell_beams, config.lone_cell_bins),
        config.lone_cell_min_neighbours,
    )
    dr_se2 = dr[:, [0, 1, 5]]
    t_s = (t_ns - t_ns[0]) * 1e-9
    if config.mode == "ground_truth":
        if gt is None:
            raise StageInputError(
                Input("keyframes", "keyframes"),
                "slam.mode is ground_truth, but the recording carries no ground truth",
            )
        pose6, cov, rows, fell_back = gt, np.zeros((len(ids), 3, 3)), [], False
        scale = None
    else:
        try:
            result = run_slam(config, dr_se2, points, t_s)
        except RuntimeError as err:  # GTSAM's, several lines long
            if "Indeterminate linear system" not in str(err):
                raise
            raise StageSettingsError(
                "GTSAM cannot solve the pose graph (an indeterminate linear system): the"
                " slam sigmas (prior_sigma_*, odom_sigma_*, heading_*) span more orders of"
                " magnitude than its solver takes; bring them nearer the defaults"
            ) from None
        pose6 = dr.copy()
        pose6[:, [0, 1, 5]] = result.poses
        pose6[:, 5] = wrap_angle(pose6[:, 5])
        cov, rows, fell_back = result.covariances, result.factors, result.fell_back
        scale = result.odometry_scale if config.mode == "slam" else None
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
    summary = slam_summary(
        config, rows, ids, dr_se2, pose6[:, [0, 1, 5]], t_s, fell_back, point_counts, scale
    )
    # summary["warnings"] are printed by the engine (a JSON output's warnings reach the
    # run's `warning:` lines), also when the artifact is found cached.
    return {
        "summary": summary,
        "poses": poses_table(ids, t_ns, pose6, cov),
        "factors": factors_table(rows, ids),
        "trajectory": tum_text(t_ns, pose6),
        "plot_points": plot_points(pose6[:, [0, 1, 5]], points, config.plot_max_points),
    }
