"""The `features` stage (paper Sec. IV.C): SOCA-CFAR detections on both polar images.

Modules:
    stage: the stage.
    cfar: the CFAR detectors.
"""

from stages.features.stage import (
    STAGE,
    FeaturesConfig,
    detect_ping,
    features_table,
    keyframe_features,
)

__all__ = ["STAGE", "FeaturesConfig", "detect_ping", "features_table", "keyframe_features"]
