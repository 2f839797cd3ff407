"""The `fuse` stage (paper Sec. IV.B): orthogonal stereo association of horizontal and vertical features.

Modules:
    stage: the stage.
"""

from stages.fuse.stage import (
    STAGE,
    ConfidenceRule,
    FuseConfig,
    assign_subproblems,
    fuse_keyframe,
    fused_points,
    image_patches,
    sonar_offset,
)

__all__ = [
    "STAGE",
    "ConfidenceRule",
    "FuseConfig",
    "assign_subproblems",
    "fuse_keyframe",
    "fused_points",
    "image_patches",
    "sonar_offset",
]
