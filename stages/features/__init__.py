"""The `features` stage (paper Sec. IV.C): SOCA-CFAR detections on both polar images.

This module declares the stage (what planning imports: no numpy, no pyarrow).

Modules:
    config: its config section.
    stage: the computation: the features table, one keyframe at a time through
        `stages.kernels.frame_features` (and `stages.kernels.cfar`).
"""

from stages.base import Input, Output, Stage
from stages.features.config import FeaturesConfig
from stages.kernels.lazy import deferred

__all__ = ["STAGE", "FeaturesConfig"]

STAGE = Stage(
    name="features",
    version=1,
    config=FeaturesConfig,
    inputs=(Input("keyframes", "frames"),),
    outputs=(
        Output(
            "features", "parquet", "features.parquet", schema="schemas.features:FEATURES_SCHEMA"
        ),
    ),
    run=deferred("stages.features.stage:run"),
    description="SOCA-CFAR detections on both polar images of every keyframe",
)
