"""The engine's front door: plan and run a dataset through a graph, summarise it.

`run`, `status`, `demo` and `sweep` all go through here so their behaviour matches.
Every function takes the graph the CLI built (`sonarmap.pipeline.engine.run.graph.Graph`);
None means the real pipeline's.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sonarmap.pipeline.engine.run.graph import Graph
from sonarmap.pipeline.engine.run.planned import PlannedStage
from sonarmap.pipeline.engine.run.planner import plan
from sonarmap.pipeline.engine.run.runner import RunResult, StageResult, execute
from sonarmap.pipeline.engine.run.session import DEFAULT_STORE, RunContext, open_context
from sonarmap.pipeline.engine.run.workers import default_workers
from sonarmap.pipeline.engine.store.artifact_store import ArtifactRef
from sonarmap.pipeline.graph import default_graph, without_figures
from sonarmap.stages.base import Stage

if TYPE_CHECKING:
    from sonarmap.pipeline.training.model_cache import ResolvedModel

__all__ = ["ModelStatus", "RunRequest", "plan_dataset", "plan_status", "run_dataset", "summarize"]

log = logging.getLogger(__name__)

MODEL_INPUTS = ("train",)
"""External inputs whose files' sha256s enter their readers' keys (`runner.plan`'s
`content_keyed`): a substituted model under an honest key never yields the honest
downstream keys (docs/exit-codes.md, Threat model)."""


@dataclass(frozen=True)
class RunRequest:
    """One dataset through the mapping graph: its config, the store, how far, what to redo.

    Attributes:
        dataset: recording file or bag directory.
        config_path: pipeline config YAML (None: the defaults).
        overrides: `section.field=value` overrides, applied after the file.
        store_dir: artifact store directory.
        until: last stage to run (None: all).
        force: stages to recompute even when cached.
        workers: stages computed side by side (None: the cores; 1: one after another).
        figures: plan the figure stages too (False: `--no-figures`, the map without its
            PNGs; `sonarmap.pipeline.graph.without_figures`).
    """

    dataset: Path
    config_path: Path | None = None
    overrides: Sequence[str] = ()
    store_dir: Path = DEFAULT_STORE
    until: str | None = None
    force: Sequence[str] = ()
    workers: int | None = None
    figures: bool = True


def _context(request: RunRequest, graph: Graph, create_store: bool = True) -> RunContext:
    ctx = open_context(
        request.dataset,
        graph,
        config_path=request.config_path,
        overrides=request.overrides,
        store_dir=request.store_dir,
        create_store=create_store,
    )
    return ctx if request.figures else replace(ctx, stages=without_figures(ctx.stages))


def _model(ctx: RunContext, until: str | None) -> ResolvedModel | None:
    """The trained classifier, when a stage up to `until` reads it (the only artifact
    from outside the dataset's graph)."""
    names = [s.name for s in ctx.stages]
    last = names.index(until) if until in names else len(names) - 1
    needs = {i.stage for s in ctx.stages[: last + 1] for i in s.inputs}
    if "train" not in needs:
        return None
    classify = getattr(ctx.config, "classify", None)
    if classify is not None and classify.model is not None:
        from sonarmap.pipeline.training.model_choice import resolve_given_model

        return resolve_given_model(
            classify.model, ctx.store, ctx.config, classify.allow_unvalidated_model
        )
    from sonarmap.pipeline.training.model_cache import resolve_default_model

    return resolve_default_model(ctx.store, ctx.config)


def _plan(
    request: RunRequest, graph: Graph, with_external: bool
) -> tuple[RunContext, list[PlannedStage], ResolvedModel | None]:
    ctx = _context(request, graph)
    model = _model(ctx, request.until) if with_external else None
    external = {} if model is None else {"train": (model.stage, model.ref)}
    planned = plan(
        ctx.stages,
        ctx.config,
        ctx.dataset,
        ctx.store,
        until=request.until,
        force=request.force,
        external=external,
        content_keyed=MODEL_INPUTS,
    )
    return ctx, planned, model


def plan_dataset(
    request: RunRequest, graph: Graph | None = None, *, with_external: bool = True
) -> tuple[RunContext, list[PlannedStage], dict[str, tuple[Stage, ArtifactRef]]]:
    """What `run` would do, without computing (with_external=False: nor training)."""
    ctx, planned, model = _plan(request, graph or default_graph(), with_external)
    return ctx, planned, {} if model is None else {"train": (model.stage, model.ref)}


@dataclass(frozen=True)
class ModelStatus:
    """The default classifier as `status` sees it, found without training or copying.

    Attributes:
        key: its planned key ("" when planning it needs the training sets simulated).
        hit: the run's store already holds it.
        reason: where `run` would take it from.
    """

    key: str
    hit: bool
    reason: str


def plan_status(
    request: RunRequest, graph: Graph | None = None
) -> tuple[RunContext, list[PlannedStage], ModelStatus | None, list[str]]:
    """What `run` would do, for every stage, the model's readers included, with no side
    effect: the model is planned from its lock (nothing simulated, trained or copied).

    Returns the context, the planned stages, the model's status (None when no stage up
    to `until` reads it) and the names of the stages that could not be planned because
    the model's key is not known yet (they all miss: `run` trains the model first).
    """
    graph = graph or default_graph()
    ctx = _context(request, graph, create_store=False)  # no side effect
    names = [s.name for s in ctx.stages]
    last = names.index(request.until) if request.until in names else len(names) - 1
    readers = [s.name for s in ctx.stages[: last + 1] if "train" in s.upstream]
    if not readers:
        return ctx, _plan_with(ctx, request, request.until, {}), None, []
    classify = getattr(ctx.config, "classify", None)
    if classify is not None and classify.model is not None:  # as `run` takes it
        from sonarmap.pipeline.training.model import training_stage_for
        from sonarmap.pipeline.training.model_choice import locate_given_model

        given = locate_given_model(
            classify.model, ctx.store, ctx.config, classify.allow_unvalidated_model
        )
        held = ctx.store.get("train", given.key) is not None
        model = ModelStatus(
            given.key, held, f"given ({classify.model})" + ("" if held else ": copied on run")
        )
        external = {"train": (training_stage_for(1, []), given)}
        return ctx, _plan_with(ctx, request, request.until, external), model, []
    from sonarmap.pipeline.training.model_cache import located_default_model

    key, ref = located_default_model(ctx.store, ctx.config)
    if ref is None:
        # The model's content enters its readers' keys (`MODEL_INPUTS`), so they cannot be
        # planned before the model exists: they all miss, and `run` trains it first.
        why = "its training sets simulated and it trained" if not key else "it trained"
        model = ModelStatus(key, False, f"not at hand: `run` needs {why}")
        # Stages that read none of the model's readers (slam after classify) are planned.
        waiting: set[str] = set()
        for stage in ctx.stages[: last + 1]:
            if {"train", *waiting} & set(stage.upstream):
                waiting.add(stage.name)
        known = [s for s in ctx.stages[: last + 1] if s.name not in waiting]
        planned = _plan_with(ctx, request, None, {}, known) if known else []
        return ctx, planned, model, [n for n in names[: last + 1] if n in waiting]
    if ref.path == ctx.store.artifact_dir("train", key):
        model = ModelStatus(key, True, "cached")
    else:
        model = ModelStatus(key, False, "in the model cache or shipped models: copied on run")
    assert graph.training is not None, "a stage reads train.model: the graph trains it"
    external = {"train": (graph.training, ref)}
    return ctx, _plan_with(ctx, request, request.until, external), model, []


def _plan_with(
    ctx: RunContext,
    request: RunRequest,
    until: str | None,
    external: Mapping[str, tuple[Stage, ArtifactRef]],
    stages: Sequence[Stage] | None = None,
) -> list[PlannedStage]:
    stages = ctx.stages if stages is None else stages
    left_out = {s.name for s in ctx.stages} - {s.name for s in stages}
    return plan(
        stages,
        ctx.config,
        ctx.dataset,
        ctx.store,
        until=until,
        force=[name for name in request.force if name not in left_out],
        external=external,
        content_keyed=MODEL_INPUTS,
    )


def run_dataset(
    request: RunRequest,
    graph: Graph | None = None,
    *,
    on_start: Callable[[PlannedStage], None] | None = None,
    on_stage: Callable[[StageResult], None] | None = None,
    scores: bool = True,
) -> tuple[RunResult, dict[str, Any]]:
    """Plan, execute and summarise one dataset through the mapping graph.

    The summary's "model" names the classifier used and where it came from; `scores`:
    whether it holds the classification scores (`summarize`).
    """
    ctx, planned, model = _plan(request, graph or default_graph(), True)
    external = {} if model is None else {"train": (model.stage, model.ref)}
    result = execute(
        planned,
        ctx.config,
        ctx.dataset,
        ctx.store,
        external=external,
        on_start=on_start,
        on_stage=on_stage,
        workers=default_workers() if request.workers is None else request.workers,
    )
    summary = summarize(ctx.stages, result.artifacts, scores=scores)
    if model is not None:
        summary["model"] = model.to_json()
    return result, summary


def _json_output(stage: Stage, ref: ArtifactRef, name: str) -> Any:
    from sonarmap.pipeline.engine.store.codecs import read_verified

    output = next((o for o in stage.outputs if o.name == name and o.kind == "json"), None)
    return None if output is None else read_verified(ref, output)


def summarize(
    stages: Sequence[Stage], artifacts: Mapping[str, ArtifactRef], *, scores: bool = True
) -> dict[str, Any]:
    """The `summary` of `run --json`: voxel counts, metrics, classification scores.

    `scores=False` leaves the classification scores out: they are the one part read from
    a Parquet table (pyarrow), which the terminal's summary never shows, so a fully
    cached run printing it loads no table at all.
    """
    by_name = {s.name: s for s in stages}
    summary: dict[str, Any] = {}
    if "keyframes" in artifacts:
        summary["keyframes"] = (
            artifacts["keyframes"].manifest.get("outputs", {}).get("keyframes", {}).get("rows")
        )
    for name in ("features", "fuse"):
        if name in artifacts:
            outputs = artifacts[name].manifest.get("outputs", {})
            summary[name] = {k: v["rows"] for k, v in outputs.items() if "rows" in v}
    if scores and "classify" in artifacts:
        from sonarmap.pipeline.engine.store.codecs import read_verified
        from sonarmap.pipeline.scoring import classification_scores

        output = next(o for o in by_name["classify"].outputs if o.name == "objects")
        summary["classification"] = classification_scores(
            read_verified(artifacts["classify"], output)
        )
    if "voxelize" in artifacts:
        vox = _json_output(by_name["voxelize"], artifacts["voxelize"], "summary") or {}
        summary["voxels"] = vox.get("voxels")
        summary["voxel_size_m"] = vox.get("voxel_size_m")
        summary["points"] = vox.get("points")
    if "evaluate" in artifacts:
        summary["metrics"] = _json_output(by_name["evaluate"], artifacts["evaluate"], "metrics")
        summary["report"] = str(artifacts["evaluate"].path / "report.md")
    return summary
