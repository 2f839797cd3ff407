"""The `infer` stage (paper Sec. IV.D-E): per-class Bayesian height models and MAP prediction.

Modules:
    stage: the stage: fit each class's model on fused points, predict 2D-only returns,
        write the models (`class_reference`, `class_cells`).
    config: InferConfig and the default classes.
    prediction: paper Eq. 1 for the predicted points.

The models themselves are kernels, shared with stage `submaps`: `stages.kernels`
`.class_models` (state, tables), `.class_query` (update and query, the loss funnel),
`.height_model` (Eq. 7-9), `.object_frame` (ICP-registered object frames, pilings),
`.beam_frame` (per-beam leading-edge frames: walls, trusses, hulls) and `.sightings`
(the input tables as per-object arrays).
"""

from stages.infer.stage import STAGE, InferConfig, infer_mission, infer_points

__all__ = ["STAGE", "InferConfig", "infer_mission", "infer_points"]
