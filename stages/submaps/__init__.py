"""The `submaps` stage: dense submaps between keyframes, anchored to their keyframe.

This module declares the stage (what planning imports: no numpy, no pyarrow).

Modules:
    config: its config section.
    stage: the computation (`frames`, `mapping`, `transfer`, `workers`: its parts).
"""

from sonarmap.stages.base import DATASET, Input, Output, Stage
from sonarmap.stages.kernels.lazy import deferred
from sonarmap.stages.submaps.config import READ_SECTIONS, SubmapsConfig

__all__ = ["STAGE", "SubmapsConfig"]

STAGE = Stage(
    name="submaps",
    # 2: points written in sorted batches of 64 frames (same rows, other Parquet pages)
    # 3: classes that borrow a beam-frame model (infer.borrowed_models, unknown_argmax_classes)
    # 4: the class models are infer's outputs, read back, and the clustering classify's
    # (same bytes); 5: frames are detected with the features stage's calibration (input
    # features.calibration), with its feature budget
    version=5,
    config=SubmapsConfig,
    inputs=(
        DATASET,
        Input("keyframes", "keyframes"),
        Input("keyframes", "sensors"),
        Input("classify", "objects"),
        Input("classify", "object_features"),
        Input("classify", "clustering"),
        Input("features", "features"),
        Input("features", "calibration"),
        Input("fuse", "fused"),
        Input("infer", "class_reference"),
        Input("infer", "class_cells"),
    ),
    outputs=(
        Output(
            "frames",
            "parquet",
            "submap_frames.parquet",
            schema="sonarmap.schemas.submaps:SUBMAP_FRAMES_SCHEMA",
        ),
        Output(
            "points",
            "parquet",
            "submap_points.parquet",
            schema="sonarmap.schemas.submaps:SUBMAP_POINTS_SCHEMA",
        ),
        Output("stats", "json", "stats.json"),
    ),
    run=deferred("sonarmap.stages.submaps.stage:_run"),
    description="dense submaps: the ping pairs between keyframes, anchored to their keyframe",
    reads_sections=(*READ_SECTIONS, "classes"),
    dataset_section="keyframes",
    key_excludes=("workers",),
)
