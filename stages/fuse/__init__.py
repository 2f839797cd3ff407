"""The `fuse` stage (paper Sec. IV.B): orthogonal stereo association of horizontal and vertical features.

This module declares the stage (what planning imports: no numpy, no pyarrow).

Modules:
    config: its config section.
    stage: the computation: the fused table, one keyframe at a time through
        `sonarmap.stages.kernels.fusion` (overlap, Eq. 3 points) and `sonarmap.stages.kernels.association`
        (Eq. 5 cost, Eq. 6 confidence).
"""

from sonarmap.stages.base import Input, Output, Stage
from sonarmap.stages.fuse.config import FuseConfig
from sonarmap.stages.kernels.lazy import deferred

__all__ = ["STAGE", "FuseConfig"]

STAGE = Stage(
    name="fuse",
    version=1,
    config=FuseConfig,
    inputs=(
        Input("keyframes", "frames"),
        Input("keyframes", "sensors"),
        Input("features", "features"),
    ),
    outputs=(
        Output("fused", "parquet", "fused.parquet", schema="sonarmap.schemas.fused:FUSED_SCHEMA"),
    ),
    run=deferred("sonarmap.stages.fuse.stage:run"),
    units=True,
    description="orthogonal stereo association of horizontal and vertical features (Eq. 3, 5, 6)",
)
