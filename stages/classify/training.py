"""The `train` stage's declaration (what planning imports: no numpy, no pyarrow); the
computation is `sonarmap.stages.classify.train`, its config `sonarmap.stages.classify.train_config`."""

from sonarmap.stages.base import Input, Output, Stage
from sonarmap.stages.classify.train_config import TrainConfig
from sonarmap.stages.kernels.lazy import deferred

__all__ = ["STAGE", "TrainConfig"]

STAGE = Stage(
    name="train",
    # 5: patches above each range's background (`patch_normalisation`), noisy sensor copies
    # 6: the no-structure class (id 0) is learned only when validation holds some of it
    # 7: metrics.json names the acceptance threshold of its validation (classify reports a
    # run's share of sure objects beside the validation's)
    # 8: settings.json, the model file's class names and settings (read without torch)
    # 9: metrics.json keeps the training's warnings (a cached model says them again)
    version=9,
    config=TrainConfig,
    inputs=(Input("keyframes", "frames"), Input("features", "features")),
    outputs=(
        Output("model", "bytes", "model.pt"),
        # optional: model folders trained before version 8 have none
        Output("settings", "json", "settings.json", optional=True),
        Output("metrics", "json", "metrics.json"),
        Output("confusion", "bytes", "confusion.png"),
        Output("curve", "bytes", "size_curve.png"),
    ),
    run=deferred("sonarmap.stages.classify.train:_run"),
    reads_sections=("classes",),
    description="train the MC-dropout object classifier on labelled keyframes",
)
