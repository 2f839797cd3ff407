"""The `slam` stage (paper Sec. IV.A): planar pose-graph SLAM over keyframes.

Modules:
    stage: the stage: config in, trajectory and loop closures out.
    config: SlamConfig, every parameter with its unit.
    frontend: the sequential front end: odometry, heading and SSM factors per keyframe.
    loops: loop closure (NSSM), PCM and the final re-registration of every loop.
    scan_matching: ICP between keyframe clouds.
    pcm: pairwise consistency maximisation of loop closures.
    pose_graph: the iSAM2 pose graph.
    points: the leading-edge points SLAM registers.
    outputs: trajectory tables and plots.
"""

from stages.slam.stage import STAGE, SlamConfig, SlamResult, run_slam

__all__ = ["STAGE", "SlamConfig", "SlamResult", "run_slam"]
