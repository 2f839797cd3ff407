"""The real pipeline's stage graph, wired from the stages, the readers and training.

The engine knows a graph only as its `Graph` type (`sonarmap.pipeline.engine.run.graph`);
what the real one holds (which stages, in which order, how a recording is found and
opened, the `frames` codec, the training stage) is decided here, above the engine, the way
a pipeline module wires its steps. The CLI and the API pass `default_graph` to whoever
needs a graph (`load_graph(spec, default_graph)`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sonarmap.pipeline.engine.run.graph import Graph
from sonarmap.stages.base import Stage

__all__ = [
    "FIGURE_STAGES",
    "all_stages",
    "default_graph",
    "extra_sections",
    "pipeline_stages",
    "required_files",
    "stage_by_name",
    "training_stage",
    "without_figures",
]

FIGURE_STAGES: tuple[str, ...] = ("figures", "map_figures")
"""The real pipeline's figure stages (`sonarmap.stages.figures`, `sonarmap.stages.map_figures`): nothing reads their outputs,
so `run --no-figures` simply plans without them (`without_figures`)."""


def default_graph() -> Graph:
    """The real pipeline: keyframes to evaluate, then the figures (`FIGURE_STAGES`);
    recordings read by `sonarmap.pipeline.readers`.

    Each stage package declares its stage; the computation (numpy, pyarrow, ...) loads
    when the stage first runs (docs/decisions/020-cached-run-imports.md).
    """
    from sonarmap.pipeline.formats.frames_codec import FRAMES_CODECS
    from sonarmap.pipeline.readers import dataset_fingerprint_parts, open_recording
    from sonarmap.pipeline.readers.referenced_files import pin_referenced_files
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
        codecs=FRAMES_CODECS,
        pin=pin_referenced_files,
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


def required_files() -> dict[str, frozenset[str]]:
    """Each real stage's files that every artifact of it holds (its outputs that are not
    optional): what `pull` and `show --verify` ask of a manifest."""
    return {
        s.name: frozenset(o.filename for o in s.outputs if not o.optional) for s in all_stages()
    }


def extra_sections() -> dict[str, Any]:
    """Config sections of the real pipeline that are not stages."""
    return dict(default_graph().extra_sections)


def stage_by_name(name: str) -> Stage:
    return default_graph().stage(name)
