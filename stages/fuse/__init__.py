"""The `fuse` stage (paper Sec. IV.B): orthogonal stereo association of horizontal and vertical features.

Modules:
    stage: the stage: its config section and the fused table, one keyframe at a time
        through `stages.kernels.fusion` (overlap, Eq. 3 points) and
        `stages.kernels.association` (Eq. 5 cost, Eq. 6 confidence).
"""

from stages.fuse.stage import STAGE, FuseConfig, fuse_table

__all__ = ["STAGE", "FuseConfig", "fuse_table"]
