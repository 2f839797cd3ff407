"""Config section `train` (`TrainConfig`): the classifier's training hyper-parameters.

Its own module so that the train stage's code stays within the file-size rule; the stage
(`sonarmap.stages.classify.train`) re-exports it.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from sonarmap.stages.base import StageConfig

__all__ = ["TrainConfig"]

NoiseLevel = Annotated[float, Field(gt=0.0, le=255.0)]
NoiseShape = Annotated[float, Field(ge=0.5, le=10.0)]  # as the simulator's noise_shape

_Filters = Annotated[int, Field(ge=1, le=1024)]


class TrainConfig(StageConfig):
    """Classifier training. Clustering/crop fields must match what classify will see."""

    eps_m: float = Field(0.25, gt=0, le=100, description="DBSCAN radius [m]")
    min_samples: int = Field(2, ge=1, le=100000, description="DBSCAN core neighbourhood size")
    min_features: int = Field(10, ge=1, le=100000, description="smallest object (paper's n)")
    margin_m: float = Field(0.2, ge=0, le=100, description="bounding-box margin on each side [m]")
    min_side_m: float = Field(
        1.0, ge=0, le=1000, description="smallest crop side [m] (keeps piling scale)"
    )
    patch_normalisation: Literal["peak", "background", "grain"] = Field(
        "background",
        description="'background': each range's median over the beams subtracted, scaled by"
        " the box's 99th percentile (a bright noise floor stays dark); 'grain': the same"
        " above each range's 90th percentile (correlated grain stays dark too); 'peak':"
        " divided by the patch maximum (models trained before patches were normalised)",
    )
    sensor_copies: int = Field(
        3,
        ge=0,
        le=64,
        description="noisy copies of every training keyframe besides the clean one, each"
        " with additive noise of another sensor (`sonarmap.stages.classify.sensor_noise`)",
    )
    sensor_noise_mean_level: tuple[NoiseLevel, NoiseLevel] = Field(
        (2.0, 128.0),
        description="mean of the added noise [8-bit levels], log-uniform between the two (either"
        " order): the span of"
        " `sonarmap.sim.randomise` (real Oculus and ARIS backgrounds 43 and 89)",
    )
    sensor_noise_shape: tuple[NoiseShape, NoiseShape] = Field(
        (0.9, 4.5), description="Weibull shape of the added noise, uniform (as sim.randomise)"
    )
    channels: tuple[_Filters, _Filters] = Field(
        (32, 64), description="conv filters; (16, 32) trains 2.5x faster, recall 0.56 vs 0.78"
    )
    hidden: int = Field(128, ge=1, le=65536)
    dropout_p: float = Field(0.05, ge=0, lt=1, description="MC dropout rate (original: 0.1)")
    spatial_dropout: bool = Field(False, description="drop whole conv channels, not units")
    epochs: int = Field(
        120, ge=1, le=100000, description="passes over the set, at most (`max_presentations`)"
    )
    batch_size: int = Field(64, ge=1, le=65536)
    max_presentations: int = Field(
        150_000,
        ge=1,
        le=10**9,
        description="sample presentations per fit at most: a larger set gets fewer epochs"
        " (at least 1). Rule: the budget the hand-written default set converges with"
        " (1,209 samples x 120 epochs = 145,080, rounded up, so that model is unchanged),"
        " so every fit, and every size of the size rule, costs at most one default training",
    )
    learning_rate: float = Field(2e-3, gt=0, le=10, description="peak of the one-cycle schedule")
    noise_std: float = Field(
        0.0, ge=0, le=10, description="Gaussian noise on [0, 1] patches (paper; off: see `augment`)"
    )
    max_rotation_deg: float = Field(
        5.0, ge=0, le=180, description="uniform in +-this (paper; small: see `augment`)"
    )
    flips: bool = Field(
        True, description="random left-right flips (mirror across the line of sight)"
    )
    flip_near_far: bool = Field(False, description="also flip near/far (unphysical for sonar)")
    min_class_samples: int = Field(
        10, ge=1, le=1000000, description="rarer classes are not learned"
    )
    split: Literal["keyframes", "dataset"] = "keyframes"
    val_block_keyframes: int = Field(10, ge=1, le=100000, description="keyframes per split block")
    val_every_blocks: int = Field(5, ge=2, le=1000, description="every n-th block validates")
    guard_keyframes: int = Field(
        3, ge=0, le=100000, description="training keyframes dropped beside val"
    )
    # The size rule (`sonarmap.stages.classify.size_rule`), with held-out datasets only.
    grow_step_datasets: int = Field(2, ge=1, le=1000, description="first size; then doubled")
    grow_min_gain_f1: float = Field(0.01, ge=0, le=1, description="held-out macro-F1 gain")
    grow_patience: int = Field(2, ge=1, le=100, description="steps without that gain to stop")
    mc_passes: int = Field(20, ge=1, le=1000, description="MC passes for the validation metrics")
    threshold: float = Field(0.99, ge=0, le=1, description="acceptance of the mean probability")
    seed: int = Field(0, ge=0, le=2**32 - 1)
