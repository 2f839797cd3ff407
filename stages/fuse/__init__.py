"""The `fuse` stage (paper Sec. IV.B): orthogonal stereo association of horizontal and vertical features.

Modules:
    stage: the stage: overlap, Eq. 3 points, the fused table.
    association: subproblems per range bin, Eq. 5 cost and Eq. 6 confidence.
"""

from stages.fuse.association import ConfidenceRule, assign_subproblems, image_patches
from stages.fuse.stage import STAGE, FuseConfig, fuse_keyframe, fused_points, sonar_offset

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
