"""Object classification (paper Sec. IV.C): the `classify` stage and the `train` stage that fits its CNN.

Modules:
    stage: the `classify` stage.
    segmentation: DBSCAN clusters of a keyframe's features and the authors' cluster rules.
    objects: the objects of a keyframe and their CNN patches.
    cnn: the object classifier network.
    view_pooling: pooling class beliefs over views of an object.
    train: the `train` stage.
    validation: the trained classifier's validation metrics and confusion figure.
    annotations: labels of simulated keyframes from the true scene.
"""

from stages.classify.stage import STAGE, ClassifyConfig, classify_keyframes
from stages.classify.train import STAGE as TRAIN_STAGE
from stages.classify.train import TrainConfig, train_classifier

__all__ = [
    "STAGE",
    "TRAIN_STAGE",
    "ClassifyConfig",
    "TrainConfig",
    "classify_keyframes",
    "train_classifier",
]
