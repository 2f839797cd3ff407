"""The `features` stage (paper Sec. IV.C): SOCA-CFAR detections on both polar images.

Modules:
    stage: the stage: its config section and the features table, one keyframe at a time
        through `stages.kernels.frame_features` (and `stages.kernels.cfar`).
"""

from stages.features.stage import STAGE, FeaturesConfig, features_table

__all__ = ["STAGE", "FeaturesConfig", "features_table"]
