"""The explicit, ordered stage registry (the only place that imports `stages`)."""

from __future__ import annotations

import functools
import importlib
import os
from typing import Any

from pipeline.engine.errors import ConfigError
from stages.base import Stage

__all__ = [
    "GRAPH_ENV",
    "all_stages",
    "alternative_graph",
    "pipeline_stages",
    "stage_by_name",
]

GRAPH_ENV = "SONARMAP_GRAPH"
"""`module:attribute` of an alternative graph object (with `.stages`, `.parts(path)` and
`.open(path, section)`): lets tests and experiments run other stage graphs through the
same engine, also in sweep workers (environment variables reach every process)."""


def alternative_graph() -> Any | None:
    """The graph named by $SONARMAP_GRAPH, or None for the real pipeline."""
    spec = os.environ.get(GRAPH_ENV)
    if not spec:
        return None
    module, _, attr = spec.partition(":")
    try:
        return getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as err:
        raise ConfigError(f"${GRAPH_ENV}={spec}: cannot load ({err})") from err


@functools.cache
def pipeline_stages() -> tuple[Stage, ...]:
    """The stages `sonarmap run` executes, in order."""
    alt = alternative_graph()
    if alt is not None:
        return tuple(alt.stages)
    from stages.classify.stage import STAGE as classify
    from stages.evaluate.stage import STAGE as evaluate
    from stages.features.stage import STAGE as features
    from stages.fuse.stage import STAGE as fuse
    from stages.infer.stage import STAGE as infer
    from stages.keyframes import STAGE as keyframes
    from stages.slam.stage import STAGE as slam
    from stages.submaps import STAGE as submaps
    from stages.voxelize import STAGE as voxelize

    return (keyframes, features, fuse, classify, slam, infer, submaps, voxelize, evaluate)


@functools.cache
def training_stage() -> Stage:
    """The classifier-training stage (its inputs are other, labelled datasets)."""
    from stages.classify.train import STAGE as train

    return train


@functools.cache
def all_stages() -> tuple[Stage, ...]:
    """Every stage with a config section: the mapping graph plus training."""
    if alternative_graph() is not None:
        return pipeline_stages()
    return (*pipeline_stages(), training_stage())


def extra_sections() -> dict[str, Any]:
    """Config sections of the engine that are not stages (none for alternative graphs)."""
    if alternative_graph() is not None:
        return {}
    from pipeline.training.config import TrainingDataConfig

    return {"training": TrainingDataConfig}


def stage_by_name(name: str) -> Stage:
    for stage in all_stages():
        if stage.name == name:
            return stage
    raise KeyError(name)
