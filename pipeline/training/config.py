"""Config section `training`: the labelled datasets the default classifier is trained on.

A leaf module (pydantic and the stage configs only), so the engine's registry can list
the section without importing the training machinery, which itself needs the engine."""

from __future__ import annotations

from pydantic import Field, field_validator

from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.training.cache_dir import default_training_directory
from sonarmap.sim.procedural_config import ProceduralConfig
from sonarmap.sim.randomise import SensorRandomisation
from sonarmap.stages.base import ConfigModel
from sonarmap.stages.features import FeaturesConfig
from sonarmap.stages.keyframes import KeyframesConfig

__all__ = ["ProceduralTraining", "TrainingDataConfig", "TrainingSet"]


class TrainingSet(ConfigModel):
    """One simulated mission the default classifier learns from."""

    scene: str = Field(min_length=1, description="a scene name in configs/scenes/ or a file")
    seed: int = Field(ge=0, le=2**32 - 1)
    goals: int = Field(ge=1, le=10000)
    duration_s: float | None = Field(None, gt=0, le=7 * 86400)
    sonars: dict[str, str] | None = Field(
        None,
        description="simulated sensor per sonar ({horizontal, vertical}: a preset of"
        " configs/sonars with an image block, or sim-clean; `sonarmap.pipeline.training."
        "sim_sensors`); null: the simulator's clean sensor",
    )

    @field_validator("sonars")
    @classmethod
    def _sonars_exist(cls, value: dict[str, str] | None) -> dict[str, str] | None:
        if value is None:
            return value
        from sonarmap.pipeline.training.sim_sensors import chosen_sensors

        if not value or set(value) - {"horizontal", "vertical"}:
            raise ValueError("sonars: a mapping of horizontal and/or vertical to a sensor name")
        try:
            chosen_sensors(None, value.get("horizontal"), value.get("vertical"), {})
        except ConfigError as err:
            raise ValueError(str(err)) from err
        return value

    @field_validator("scene")
    @classmethod
    def _scene_exists(cls, value: str) -> str:
        # Checked with the rest of the config, not when training first needs it.
        from sonarmap.pipeline.training.datasets import scene_path

        try:
            scene_path(value)
        except ConfigError as err:
            raise ValueError(str(err)) from err
        return value


class ProceduralTraining(ConfigModel):
    """Random harbours (`sonarmap.sim.procedural`) the default classifier learns from, each with the
    simulator's own mission and a randomised sensor (`sonarmap.sim.randomise`).

    Training worlds have seeds base_seed, base_seed + 1, ...; the held-out validation
    worlds follow them. The `train` stage adds training worlds in that order until the
    held-out macro-F1 stops improving (`train.grow_*`), so `worlds` is a ceiling.
    """

    generator: ProceduralConfig = Field(
        default_factory=ProceduralConfig, description="the generator's ranges (`sonarmap.sim.procedural`)"
    )
    worlds: int = Field(
        6,
        ge=1,
        le=1000,
        description="training worlds at most; 6: with the 2 hand-written sets the size rule's"
        " doubling tries 2, 4, 8 datasets, three fits, which is what fits the 15 min on 2"
        " cores (docs/decisions/018)",
    )
    validation_worlds: int = Field(
        2, ge=1, le=100, description="held-out worlds that validate every size of the set"
    )
    base_seed: int = Field(
        1000, ge=0, le=2**32 - 2000, description="seed of the first world (far from the study's)"
    )
    goals: int = Field(3, ge=1, le=10000, description="mission goals per world")
    duration_s: float | None = Field(
        None, gt=0, le=7 * 86400, description="cut each mission after this time (null: whole)"
    )
    sensor: SensorRandomisation | None = Field(
        default_factory=SensorRandomisation,
        description="per-mission sensor draw (`sonarmap.sim.randomise`); null: the default sensor",
    )


class TrainingDataConfig(ConfigModel):
    """Config section `training`: which labelled datasets the default model is trained on.

    The mapped scene should not be among them (the default marina never is). Seeds are
    far from the study's 0..N-1. Simulated files go to `directory` and are reused; the
    trained models go to the model cache `<directory>/store` (`sonarmap.pipeline.training.model_cache`),
    which every store of the user reuses. `directory` defaults to the user's cache
    directory (`sonarmap.pipeline.training.cache_dir`), not to the working directory.
    """

    sets: tuple[TrainingSet, ...] = Field(
        default=(
            TrainingSet(scene="harbour", seed=100, goals=12, duration_s=None),
            TrainingSet(scene="pier", seed=101, goals=6, duration_s=None),
        ),
        description="hand-written scenes to train on, before any procedural worlds",
    )
    procedural: ProceduralTraining | None = Field(
        default=None,
        description="procedural training worlds (`training: {procedural: {}}` for the"
        " generator's defaults); null: `sets` and `recorded` only. Off by default: its model"
        " maps the demo marina worse, 4.9x accurate voxels against 5.2x (docs/decisions/018)",
    )
    directory: str = Field(
        default_factory=lambda: str(default_training_directory()),
        min_length=1,
        description="training datasets and the model cache (`<directory>/store`); default:"
        " `<user cache dir>/sonarmap/training`, or `$SONARMAP_CACHE_DIR/training` when set",
    )
    recorded: tuple[str, ...] = Field(
        default=(),
        description="field recordings to train on too; each needs <stem>.annotations.yaml beside it",
    )
    keyframes: KeyframesConfig = Field(
        default_factory=KeyframesConfig, description="keyframe selection of the training datasets"
    )
    # model_validate: mypy reads the stage's positional Field defaults as required fields.
    features: FeaturesConfig = Field(
        default_factory=lambda: FeaturesConfig.model_validate({}),
        description="CFAR features of the training datasets",
    )
    shipped_models: str | None = Field(
        default="configs/model",
        description="read-only store of pretrained default models with the lock of their"
        " training recordings (`sonarmap.pipeline.training.shipped`; relative: to the project);"
        " null: always simulate and train here",
    )
    follow_run: bool = Field(
        default=False,
        description="build the training datasets with the run's keyframes/features sections"
        " instead (a model matched to them, trained once per setting)",
    )
