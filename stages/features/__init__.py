"""The `features` stage (paper Sec. IV.C): SOCA-CFAR detections on both polar images.

This module declares the stage (what planning imports: no numpy, no pyarrow).

Modules:
    config: its config section.
    calibration: the calibration (`calibration.json`) and its flood / starve warnings.
    stage: the computation: the features table, one keyframe at a time through
        `sonarmap.stages.kernels.frame_features` (and `sonarmap.stages.kernels.cfar`).
"""

from sonarmap.stages.base import Input, Output, Stage
from sonarmap.stages.features.config import FeaturesConfig
from sonarmap.stages.kernels.lazy import deferred

__all__ = ["STAGE", "FeaturesConfig"]

STAGE = Stage(
    name="features",
    # 2: thresholds calibrated from the recording per sonar and range band (issue 50),
    # recorded in calibration.json; a per-keyframe feature budget. 3: a flood is never
    # also a starve. 4: denoise auto sizes the mean to the grain's correlation.
    # 5: the calibration samples keyframes on a grid of absolute time (stable when a
    # recording is extended or trimmed); per-keyframe detection units (issue 53).
    # 6: calibrated on the ping pairs stage `keyframes` samples on that grid, whatever the
    # keyframe selection (a spacing sweep calibrates once); calibration.json names their
    # times (`sampled_t_ns`).
    # 7: sampled pings holding one level in every pixel (blank, saturated) are left out of
    # the calibration with a warning (`constant_t_ns`); each sampled ping's median level is
    # recorded (`median_levels`), and a step by half again warns (a gain or range change).
    version=7,
    config=FeaturesConfig,
    inputs=(
        Input("keyframes", "frames"),
        Input("keyframes", "keyframes"),
        Input("keyframes", "calibration_frames"),
    ),
    outputs=(
        Output(
            "features",
            "parquet",
            "features.parquet",
            schema="sonarmap.schemas.features:FEATURES_SCHEMA",
        ),
        Output("calibration", "json", "calibration.json"),
    ),
    input_columns=((Input("keyframes", "keyframes"), ("keyframe_id", "t_ns")),),
    run=deferred("sonarmap.stages.features.stage:run"),
    units=True,
    description="SOCA-CFAR detections on both polar images of every keyframe, thresholds"
    " calibrated from the recording",
)
