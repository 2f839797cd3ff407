"""The classify settings that choose its model (kept out of its key: the key follows the
chosen model's bytes instead, `sonarmap.pipeline.api.MODEL_INPUTS`)."""

from __future__ import annotations

from pydantic import Field

from sonarmap.stages.base import StageConfig

__all__ = ["MODEL_CHOICE_FIELDS", "ModelChoice"]


class ModelChoice(StageConfig):
    """Which trained model classify uses."""

    model: str | None = Field(
        None,
        max_length=4096,
        description="a trained model: a train artifact's folder or train/<key>; None: the default",
    )
    allow_unvalidated_model: bool = Field(
        False, description="accept a `model` trained without a validation split"
    )


MODEL_CHOICE_FIELDS: tuple[str, ...] = tuple(ModelChoice.model_fields)
