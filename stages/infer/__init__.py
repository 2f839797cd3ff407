"""The `infer` stage (paper Sec. IV.D-E): per-class Bayesian height models and MAP prediction.

Modules:
    stage: the stage: fit each class's model on fused points, predict 2D-only returns.
    config: InferConfig and the default classes.
    inputs: the stage's input tables as arrays.
    prediction: update and query of one class's model with one keyframe, the loss funnel.
    height_model: the Bayesian height model (paper Eq. 7-9).
    object_frame: object-centred frames registered by ICP (pilings).
    beam_frame: per-beam leading-edge frames (walls, trusses, hulls).
"""

from stages.infer.stage import STAGE, InferConfig, infer_mission, infer_points

__all__ = ["STAGE", "InferConfig", "infer_mission", "infer_points"]
