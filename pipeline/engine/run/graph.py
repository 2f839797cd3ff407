"""The stage graph: the real pipeline's, or an alternative one (the only place that
imports `stages`' stage modules).

The CLI builds the graph once (`load_graph` of `$SONARMAP_GRAPH`, read there and
nowhere else) and passes it to the session, planner, sweep workers and commands.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.stages.base import Stage

__all__ = [
    "FIGURE_STAGES",
    "GRAPH_ENV",
    "Graph",
    "all_stages",
    "default_graph",
    "extra_sections",
    "load_graph",
    "pipeline_stages",
    "stage_by_name",
    "training_stage",
    "without_figures",
]

FIGURE_STAGES: tuple[str, ...] = ("figures", "map_figures")
"""The real pipeline's figure stages (`sonarmap.stages.figures`, `sonarmap.stages.map_figures`): nothing reads their outputs,
so `run --no-figures` simply plans without them (`without_figures`)."""

GRAPH_ENV = "SONARMAP_GRAPH"
"""`module:attribute` of an alternative graph (a `Graph`, or any object with `.stages`,
`.parts(path)` and `.open(path, section)`): lets tests and experiments run other stage
graphs through the same engine. Read by the CLI only."""


@dataclass(frozen=True)
class Graph:
    """The stages a run executes and how it finds and opens its dataset.

    Attributes:
        stages: the mapping stages, in order (the first reads `DATASET`).
        parts: path -> the files whose contents fingerprint the dataset.
        open: (path, the reading stage's config section) -> the object bound to its
            `DATASET` input (a `sonarmap.schemas.recording.Recording` for the real pipeline).
        training: the classifier-training stage (None: the graph trains nothing).
        extra_sections: config sections of the engine that are not stages.
        spec: the `module:attribute` it was loaded from (None: the real pipeline).
    """

    stages: tuple[Stage, ...]
    parts: Callable[[Path], Sequence[Path]]
    open: Callable[[Path, Any], Any]
    training: Stage | None = None
    extra_sections: Mapping[str, type[BaseModel]] = field(default_factory=dict)
    spec: str | None = None

    @property
    def config_stages(self) -> tuple[Stage, ...]:
        """Every stage with a config section: the mapping stages, then training."""
        return self.stages if self.training is None else (*self.stages, self.training)

    def stage(self, name: str) -> Stage:
        for stage in self.config_stages:
            if stage.name == name:
                return stage
        raise KeyError(name)


def default_graph() -> Graph:
    """The real pipeline: keyframes to evaluate, then the figures (`FIGURE_STAGES`);
    recordings read by `sonarmap.pipeline.readers`.

    Each stage package declares its stage; the computation (numpy, pyarrow, ...) loads
    when the stage first runs (docs/decisions/020-cached-run-imports.md).
    """
    from sonarmap.pipeline.readers import dataset_fingerprint_parts, open_recording
    from sonarmap.pipeline.training.config import TrainingDataConfig
    from sonarmap.schemas.classes import ClassTable
    from sonarmap.stages.classify import STAGE as classify
    from sonarmap.stages.classify.training import STAGE as train
    from sonarmap.stages.evaluate import STAGE as evaluate
    from sonarmap.stages.features import STAGE as features
    from sonarmap.stages.figures import STAGE as figures
    from sonarmap.stages.fuse import STAGE as fuse
    from sonarmap.stages.infer import STAGE as infer
    from sonarmap.stages.keyframes import STAGE as keyframes
    from sonarmap.stages.map_figures import STAGE as map_figures
    from sonarmap.stages.slam import STAGE as slam
    from sonarmap.stages.submaps import STAGE as submaps
    from sonarmap.stages.voxelize import STAGE as voxelize

    mapping = (keyframes, features, fuse, classify, slam, infer, submaps, voxelize, evaluate)
    return Graph(
        stages=(*mapping, figures, map_figures),
        parts=dataset_fingerprint_parts,
        open=open_recording,
        training=train,
        extra_sections={"training": TrainingDataConfig, "classes": ClassTable},
    )


def without_figures(stages: Sequence[Stage]) -> tuple[Stage, ...]:
    """`stages` less the figure stages (`FIGURE_STAGES`; a stage reading one of them stays
    out too, so the plan never lacks a producer)."""
    dropped = set(FIGURE_STAGES)
    kept = []
    for stage in stages:
        if stage.name in dropped or dropped & set(stage.upstream):
            dropped.add(stage.name)
        else:
            kept.append(stage)
    return tuple(kept)


def load_graph(spec: str | None) -> Graph:
    """The graph named by `spec` (`module:attribute`), or the real pipeline's (None, "")."""
    if not spec:
        return default_graph()
    module, _, attr = spec.partition(":")
    try:
        found = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError, ValueError) as err:
        raise ConfigError(f"${GRAPH_ENV}={spec[:200]}: cannot load ({err})") from err
    if isinstance(found, Graph):
        return found if found.spec == spec else Graph(**{**found.__dict__, "spec": spec})
    try:
        stages = tuple(found.stages)
        graph = Graph(stages=stages, parts=found.parts, open=found.open, spec=spec)
    except (AttributeError, TypeError) as err:
        raise ConfigError(f"${GRAPH_ENV}={spec[:200]}: not a stage graph ({err})") from err
    if not stages or not all(isinstance(s, Stage) for s in stages):
        raise ConfigError(f"${GRAPH_ENV}={spec[:200]}: not a stage graph (no stages)")
    return graph


# Shorthands for the real pipeline (config tools and tests); they read no environment.
def pipeline_stages() -> tuple[Stage, ...]:
    """The real pipeline's mapping stages, in order."""
    return default_graph().stages


def training_stage() -> Stage:
    """The real pipeline's classifier-training stage."""
    train = default_graph().training
    assert train is not None
    return train


def all_stages() -> tuple[Stage, ...]:
    """Every stage of the real pipeline with a config section (mapping plus training)."""
    return default_graph().config_stages


def extra_sections() -> dict[str, Any]:
    """Config sections of the real pipeline that are not stages."""
    return dict(default_graph().extra_sections)


def stage_by_name(name: str) -> Stage:
    return default_graph().stage(name)
