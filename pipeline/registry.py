"""The explicit, ordered stage registry (the only place that imports `stages`)."""

from __future__ import annotations

import functools

from stages.base import Stage

__all__ = ["STAGE_NAMES", "all_stages", "pipeline_stages", "stage_by_name"]

STAGE_NAMES: tuple[str, ...] = (
    "keyframes",
    "features",
    "fuse",
    "classify",
    "slam",
    "infer",
    "voxelize",
    "evaluate",
)
"""The mapping graph in execution order (a topological order of DESIGN.md's graph)."""


@functools.cache
def pipeline_stages() -> tuple[Stage, ...]:
    """The stages `sonarmap run` executes, in order."""
    from stages.classify import STAGE as classify
    from stages.evaluate import STAGE as evaluate
    from stages.features import STAGE as features
    from stages.fuse import STAGE as fuse
    from stages.infer import STAGE as infer
    from stages.keyframes import STAGE as keyframes
    from stages.slam import STAGE as slam
    from stages.voxelize import STAGE as voxelize

    return (keyframes, features, fuse, classify, slam, infer, voxelize, evaluate)


@functools.cache
def training_stage() -> Stage:
    """The classifier-training stage (its inputs are other, labelled datasets)."""
    from stages.train import STAGE as train

    return train


@functools.cache
def all_stages() -> tuple[Stage, ...]:
    """Every stage with a config section: the mapping graph plus training."""
    return (*pipeline_stages(), training_stage())


def stage_by_name(name: str) -> Stage:
    for stage in all_stages():
        if stage.name == name:
            return stage
    raise KeyError(name)
