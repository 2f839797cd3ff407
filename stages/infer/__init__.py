"""The `infer` stage (paper Sec. IV.D-E): per-class Bayesian height models and MAP prediction.

This module declares the stage (what planning imports: no numpy, no pyarrow).

Modules:
    stage: the computation: fit each class's model on fused points, predict 2D-only returns,
        write the models (`class_reference`, `class_cells`).
    config: InferConfig and the default classes.
    prediction: paper Eq. 1 for the predicted points.

The models themselves are kernels, shared with stage `submaps`: `sonarmap.stages.kernels`
`.class_models` (state, tables), `.class_query` (update and query, the loss funnel),
`.height_model` (Eq. 7-9), `.object_frame` (ICP-registered object frames, pilings),
`.beam_frame` (per-beam leading-edge frames: walls, trusses, hulls) and `.sightings`
(the input tables as per-object arrays).
"""

from sonarmap.stages.base import Input, Output, Stage
from sonarmap.stages.infer.config import InferConfig
from sonarmap.stages.kernels.lazy import deferred

__all__ = ["STAGE", "InferConfig"]

STAGE = Stage(
    name="infer",
    # 3: the mixture rule keeps linear Dirichlet counts (confidences change by ~1e-13)
    # 4: the learned class models are outputs (class_reference, class_cells)
    # 5: a provisional reference frame gives way to the next sighting it cannot register
    version=5,
    config=InferConfig,
    reads_sections=("classes",),
    inputs=(
        Input("classify", "objects"),
        Input("classify", "object_features"),
        Input("features", "features"),
        Input("fuse", "fused"),
    ),
    outputs=(
        Output(
            "points", "parquet", "points.parquet", schema="sonarmap.schemas.points:POINTS_SCHEMA"
        ),
        Output("stats", "json", "stats.json"),
        Output(
            "class_reference",
            "parquet",
            "class_reference.parquet",
            schema="sonarmap.schemas.class_models:CLASS_REFERENCE_SCHEMA",
        ),
        Output(
            "class_cells",
            "parquet",
            "class_cells.parquet",
            schema="sonarmap.schemas.class_models:CLASS_CELLS_SCHEMA",
        ),
    ),
    run=deferred("sonarmap.stages.infer.stage:_run"),
    description="object-class Bayesian height models; MAP heights for 2D-only returns",
)
