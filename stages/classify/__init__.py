"""Object classification (paper Sec. IV.C): the `classify` stage and the `train` stage that fits its CNN.

This module declares the `classify` stage (what planning imports: no numpy, no pyarrow);
the `train` stage is declared in `train`.

Modules:
    config: the `classify` config section.
    stage: the `classify` computation.
    segmentation: DBSCAN clusters of a keyframe's features and the authors' cluster rules.
    objects: the objects of a keyframe and their CNN patches.
    cnn: the object classifier network.
    view_pooling: pooling class beliefs over views of an object.
    train: the `train` stage.
    validation: the trained classifier's validation metrics and confusion figure.
    annotations: labels of simulated keyframes from the true scene.
"""

from sonarmap.stages.base import Input, Output, Stage
from sonarmap.stages.classify.config import ClassifyConfig
from sonarmap.stages.classify.model_choice import MODEL_CHOICE_FIELDS
from sonarmap.stages.kernels.lazy import deferred

__all__ = ["STAGE", "ClassifyConfig"]

STAGE = Stage(
    name="classify",
    # 5: output `clustering` (what submaps clusters its frames with)
    # 6: MC-dropout masks shared by one keyframe's objects, numpy-drawn (mc_predict_groups)
    # 7: overlay.png moves to the `figures` stage (config `figures.overlay`)
    # 8: patches normalised as the model file says (`patch_normalisation`, issue 50)
    # 9: the CNN runs one keyframe per call (float32 rounding of batched products moves);
    # per-keyframe work units (issue 53). 10: dropout seeded by the keyframe's ping time
    # (was its id) and units keyed without feature ids, so sweep points share them
    # 11: acceptance.json, the shares of objects accepted in single views and pooled (and
    # the validation split's), warned when pooling accepts fewer (input train.metrics)
    # 12: the CNN is loaded only when a keyframe's unit must be computed (input
    # train.settings: the class names and settings without torch)
    # 13: a compact class (object frame) is accepted only where `min_views` sightings of
    # its place pool (and, opt-in, `min_seen_share` of the keyframes whose fan covered it
    # sighted it); acceptance.json counts the sure objects held back; units are keyed
    # without the decision's settings
    # 14: acceptance.json warns of a class the table infers that the model cannot output
    version=14,
    config=ClassifyConfig,
    inputs=(
        Input("keyframes", "frames"),
        Input("keyframes", "keyframes"),
        Input("keyframes", "sensors"),
        Input("features", "features"),
        Input("train", "model"),
        Input("train", "metrics"),
        Input("train", "settings"),
    ),
    outputs=(
        Output(
            "objects",
            "parquet",
            "objects.parquet",
            schema="sonarmap.schemas.objects:OBJECTS_SCHEMA",
        ),
        Output(
            "object_features",
            "parquet",
            "object_features.parquet",
            schema="sonarmap.schemas.objects:OBJECT_FEATURES_SCHEMA",
        ),
        Output("clustering", "json", "clustering.json"),
        Output("acceptance", "json", "acceptance.json"),
    ),
    run=deferred("sonarmap.stages.classify.stage:_run"),
    key_excludes=MODEL_CHOICE_FIELDS,
    reads_sections=("classes",),
    units=True,
    description="DBSCAN objects of horizontal features, classified by an MC-dropout CNN,"
    " pooled over the keyframes that see them",
)
