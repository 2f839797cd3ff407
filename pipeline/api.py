"""The engine's front door for the real pipeline: plan and run a dataset, summarise it.

`run`, `status`, `demo` and `sweep` all go through here so their behaviour matches.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from pipeline.codecs import read_verified
from pipeline.runner import PlannedStage, RunResult, StageResult, execute, plan
from pipeline.session import DEFAULT_STORE, RunContext, make_context
from pipeline.store import ArtifactRef
from stages.base import Stage

__all__ = ["plan_dataset", "run_dataset", "summarize"]

log = logging.getLogger(__name__)


def _context(
    dataset: Path, config_path: Path | None, overrides: Sequence[str], store_dir: Path
) -> RunContext:
    from pipeline.registry import all_stages, extra_sections, pipeline_stages

    return make_context(
        dataset,
        stages=pipeline_stages(),
        config_stages=all_stages(),
        extra_sections=extra_sections(),
        config_path=config_path,
        overrides=overrides,
        store_dir=store_dir,
    )


def _external(ctx: RunContext, until: str | None) -> dict[str, tuple[Stage, ArtifactRef]]:
    """Artifacts from outside the dataset's graph (the trained classifier)."""
    names = [s.name for s in ctx.stages]
    last = names.index(until) if until in names else len(names) - 1
    needs = {i.split(".")[0] for s in ctx.stages[: last + 1] for i in s.inputs}
    if "train" not in needs:
        return {}
    from pipeline.training import resolve_model

    return {"train": resolve_model(ctx.store, ctx.config)}


def plan_dataset(
    dataset: Path,
    *,
    config_path: Path | None = None,
    overrides: Sequence[str] = (),
    store_dir: Path = DEFAULT_STORE,
    until: str | None = None,
    force: Sequence[str] = (),
    with_external: bool = True,
) -> tuple[RunContext, list[PlannedStage], dict[str, tuple[Stage, ArtifactRef]]]:
    ctx = _context(dataset, config_path, overrides, store_dir)
    external = _external(ctx, until) if with_external else {}
    planned = plan(
        ctx.stages, ctx.config, ctx.dataset, ctx.store, until=until, force=force, external=external
    )
    return ctx, planned, external


def run_dataset(
    dataset: Path,
    *,
    config_path: Path | None = None,
    overrides: Sequence[str] = (),
    store_dir: Path = DEFAULT_STORE,
    until: str | None = None,
    force: Sequence[str] = (),
    on_start: Callable[[PlannedStage], None] | None = None,
    on_stage: Callable[[StageResult], None] | None = None,
) -> tuple[RunResult, dict[str, Any]]:
    """Plan, execute and summarise one dataset through the mapping graph."""
    ctx, planned, external = plan_dataset(
        dataset,
        config_path=config_path,
        overrides=overrides,
        store_dir=store_dir,
        until=until,
        force=force,
    )
    result = execute(
        planned,
        ctx.config,
        ctx.dataset,
        ctx.store,
        external=external,
        on_start=on_start,
        on_stage=on_stage,
    )
    return result, summarize(ctx.stages, result.artifacts)


def _json_output(stage: Stage, ref: ArtifactRef, name: str) -> Any:
    output = next((o for o in stage.outputs if o.name == name and o.kind == "json"), None)
    return None if output is None else read_verified(ref, output)


def summarize(stages: Sequence[Stage], artifacts: Mapping[str, ArtifactRef]) -> dict[str, Any]:
    """The `summary` of `run --json`: voxel counts, metrics, classification scores."""
    by_name = {s.name: s for s in stages}
    summary: dict[str, Any] = {}
    if "keyframes" in artifacts:
        summary["keyframes"] = (
            artifacts["keyframes"].manifest.get("outputs", {}).get("keyframes", {}).get("rows")
        )
    for name in ("features", "fuse"):
        if name in artifacts:
            outputs = artifacts[name].manifest.get("outputs", {})
            summary[name] = {k: v.get("rows") for k, v in outputs.items()}
    if "classify" in artifacts:
        from pipeline.scoring import classification_scores

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
