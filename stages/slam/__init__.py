"""The `slam` stage (paper Sec. IV.A): planar pose-graph SLAM over keyframes.

This module declares the stage (what planning imports: no numpy, no pyarrow).

Modules:
    stage: the computation: config in, trajectory and loop closures out.
    config: SlamConfig, every parameter with its unit.
    frontend: the sequential front end: odometry, heading and SSM factors per keyframe.
    loops: loop closure (NSSM), PCM and the final re-registration of every loop.
    scan_matching: ICP between keyframe clouds.
    degeneracy: which directions of SE(2) a scan match constrains.
    pcm: pairwise consistency maximisation of loop closures.
    health: summary.json, what the stage can say about its result without ground truth.
    pose_graph: the iSAM2 pose graph.
    points: the leading-edge points SLAM registers.
    thinning: those points thinned on a voxel grid and outlier-filtered before ICP.
    outputs: trajectory tables and the points trajectory.png draws.
"""

from sonarmap.stages.base import Input, Output, Stage
from sonarmap.stages.kernels.lazy import deferred
from sonarmap.stages.slam.config import SlamConfig

__all__ = ["STAGE", "SlamConfig"]

STAGE = Stage(
    name="slam",
    # 10: trajectory.png moves to the `figures` stage; plot_points.parquet is what it draws
    # 11: scan matches free along the directions they leave unconstrained (degeneracy),
    # sequential ones gated against the step's odometry (Mahalanobis) under a Huber kernel;
    # factors.parquet gains `degenerate`; summary.json (health: SLAM vs dead reckoning)
    # 12: each keyframe's points thinned on the voxel grid and outlier-filtered (radius
    # 1.0 m, 5 neighbours) before scan matching, all keyframes in one pass, then held to
    # max_points_per_keyframe (the densest kept); summary.json gains `points` (what thinning,
    # the filter and the budget dropped) and their warnings
    # 13: leading edges with fewer than 3 other detections within +-2 beams, +-6 range bins
    # of them in their image are dropped as lone false alarms (counted in cells: the front
    # end's rate is per cell); min_points and min_overlap_points 30 -> 10 (lone pilings);
    # summary.json's `points` gains `lone_cells_removed`; loop targets from a k-d tree over
    # the older keyframes' positions, at most nssm_max_candidates (100) nearest ones
    # (`loop_max_view_change_deg`, off by default, rejects loops seen from another side)
    # 14: summary.json's `fallback` says when no scan match proposed was accepted (the
    # trajectory is then dead reckoning's where SLAM was asked for), with the reasons
    # 16 (15 was a reverted loop rule): odom_scale_sigma 0.02 -> 0.01, the simulator's
    # default navigation like the other navigation factors; the summary's predicted drift
    # adds the scale error's (a dilation of the track about its start)
    # 17: summary.json's `odometry_scale_error` is the state's estimate, a warning beyond
    # the prior's 99 %
    version=17,
    config=SlamConfig,
    inputs=(
        Input("keyframes", "keyframes"),
        Input("keyframes", "sensors"),
        Input("features", "features"),
    ),
    outputs=(
        Output("poses", "parquet", "poses.parquet", schema="sonarmap.schemas.slam:POSES_SCHEMA"),
        Output(
            "factors", "parquet", "factors.parquet", schema="sonarmap.schemas.slam:FACTORS_SCHEMA"
        ),
        Output("trajectory", "bytes", "trajectory.tum"),
        Output("summary", "json", "summary.json"),
        Output(
            "plot_points",
            "parquet",
            "plot_points.parquet",
            schema="sonarmap.schemas.figures:PLOT_POINTS_SCHEMA",
        ),
    ),
    run=deferred("sonarmap.stages.slam.stage:run"),
    description="planar pose-graph SLAM (iSAM2): scan matching, loop closures with PCM",
)
