"""The runner: compute a plan's misses in order and commit them.

Each miss is computed under its key's lock in the store: the runner binds upstream
artifacts (and, for the stage reading `DATASET`, the dataset the graph opens) to the
stage's inputs, calls the stage, validates its outputs and commits them atomically.
The plan comes from `pipeline.engine.planner`.
"""

from __future__ import annotations

import logging
import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from pipeline.engine import output_checks
from pipeline.engine.codecs import read_verified, write_output
from pipeline.engine.disk import disk_error
from pipeline.engine.errors import (
    ConfigError,
    PipelineError,
    SourceError,
    StageFailed,
    StoreError,
)
from pipeline.engine.leases import RunLease
from pipeline.engine.planned import DatasetSpec, PlannedStage
from pipeline.engine.planner import plan
from pipeline.engine.run_records import record_run
from pipeline.engine.store import ArtifactRef, ArtifactStore
from pipeline.engine.text import display_path
from stages.base import Input, Output, Stage, StageInputError
from stages.kernels.parallel import release_memory

__all__ = ["DatasetSpec", "PlannedStage", "RunResult", "StageResult", "execute", "plan"]

log = logging.getLogger(__name__)
_REASON_CHARS = 200
"""Most characters of a stage's refusal quoted in the error line."""
_VERSIONED = ("sonarmap", "numpy", "pyarrow", "mcap", "rosbags", "torch", "gtsam", "open3d-cpu")


@dataclass(frozen=True)
class StageResult:
    stage: str
    key: str
    status: str  # "hit" | "computed" | "reused" (another process computed it while we waited)
    seconds: float
    path: str
    reason: str = ""
    warnings: tuple[str, ...] = ()


@dataclass
class RunResult:
    dataset: str
    store: str
    stages: list[StageResult] = field(default_factory=list)
    artifacts: dict[str, ArtifactRef] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    """Empty or collapsed outputs (`pipeline.engine.output_checks`), one line each."""

    def to_json(self) -> dict[str, Any]:
        return {
            "dataset": self.dataset,
            "store": self.store,
            "stages": [r.__dict__ for r in self.stages],
            "warnings": list(self.warnings),
        }


def _software_versions() -> dict[str, str]:
    versions = {}
    for name in _VERSIONED:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return versions


def _output(stage: Stage, producer: Stage, item: Input) -> Output:
    output = next((o for o in producer.outputs if o.name == item.output), None)
    if output is None:
        raise ConfigError(f"stage {stage.name}: {item.stage} has no output '{item.output}'")
    return output


def _bind_inputs(
    item: PlannedStage,
    refs: Mapping[str, ArtifactRef],
    outputs_of: Mapping[str, Stage],
    dataset: DatasetSpec,
    config: BaseModel,
    verified: set[tuple[str, str, str]],
    opened: dict[str, Any],
) -> dict[str, Any]:
    """The stage's `run` mapping: each input's value under its `Input.name`, and the
    sections it reads under "config.<section>". A json output with a `record` type is
    handed over as that record; a file it refuses is bad input naming that file.

    The dataset is opened by the graph's `open` once per run and config section
    (`opened`): the stages reading it (keyframes, submaps) share what it has read."""
    stage = item.stage
    inputs: dict[str, Any] = {f"config.{s}": getattr(config, s) for s in stage.reads_sections}
    columns = dict(stage.input_columns)
    for name in stage.inputs:
        if name.is_dataset:
            section = getattr(config, stage.dataset_section or stage.name)
            once = section.model_dump_json() if isinstance(section, BaseModel) else repr(section)
            if once not in opened:
                opened[once] = dataset.open(dataset.path, section)
            inputs[name.name] = opened[once]
            continue
        output = _output(stage, outputs_of[name.stage], name)
        value = read_verified(refs[name.stage], output, verified, columns.get(name))
        if output.record is not None and value is not None:
            try:
                value = output.record.from_json(value)
            except ValueError as err:
                rejected = StageInputError(name, str(err))
                raise _rejected_input(rejected, stage, refs, outputs_of, dataset) from err
        inputs[name.name] = value
    return inputs


def _rejected_input(
    err: StageInputError,
    stage: Stage,
    refs: Mapping[str, ArtifactRef],
    outputs_of: Mapping[str, Stage],
    dataset: DatasetSpec,
) -> SourceError:
    """A stage's refusal of an input, naming the file behind it (artifact or dataset)."""
    item = err.input
    where = str(dataset.path) if item.is_dataset else item.name
    if item.stage in refs and item.stage in outputs_of:
        output = next((o for o in outputs_of[item.stage].outputs if o.name == item.output), None)
        ref = refs[item.stage]
        filename = output.filename if output is not None else item.output
        where = f"{ref.stage}/{ref.key}/{filename}"
    # The stage's first line, cut to a short prefix: the whole line stays a few hundred
    # characters whatever the stage put in it.
    reason = (err.reason.splitlines() or [""])[0]
    reason = reason if len(reason) <= _REASON_CHARS else reason[:_REASON_CHARS] + "..."
    return SourceError(f"{where}: {reason} (input of stage {stage.name})")


def _compute(
    item: PlannedStage,
    section: Any,
    inputs: Mapping[str, Any],
    tmp: Path,
    refs: Mapping[str, ArtifactRef],
    outputs_of: Mapping[str, Stage],
    dataset: DatasetSpec,
) -> dict[str, Any]:
    """Run the stage and write its outputs into `tmp`; the manifest's extra fields.

    A `StageInputError` becomes bad input (exit 2) naming the file behind the input;
    any other exception of the stage is a `StageFailed` (exit 1).
    """
    stage = item.stage
    provenance = {"stage": stage.name, "version": str(stage.version), "key": item.key}
    try:
        values = stage.run(section, inputs)
        facts: dict[str, Any] = {}
        for output in stage.outputs:
            value = values.get(output.name)
            if value is None:
                if not output.optional:
                    raise StageFailed(f"stage {stage.name}: output '{output.name}' missing")
                continue
            facts[output.name] = write_output(tmp, stage.name, output, value, provenance)
    except (PipelineError, OSError):
        raise  # OSError: a full or read-only disk, reported by `execute` (exit 2)
    except StageInputError as err:
        raise _rejected_input(err, stage, refs, outputs_of, dataset) from err
    except Exception as err:
        raise StageFailed(f"stage {stage.name} failed: {type(err).__name__}: {err}") from err
    return {"outputs": facts}


def execute(
    planned: Sequence[PlannedStage],
    config: BaseModel,
    dataset: DatasetSpec,
    store: ArtifactStore,
    *,
    external: Mapping[str, tuple[Stage, ArtifactRef]] | None = None,
    on_stage: Callable[[StageResult], None] | None = None,
    on_start: Callable[[PlannedStage], None] | None = None,
) -> RunResult:
    """Compute the misses in order and commit them; hits are only looked up.

    While it runs, a lease on the store holds every planned and external address, so
    `gc` leaves them alone; the run record is rewritten as each stage commits, so an
    interrupted run's finished stages stay referenced. Any OSError from the store or
    the dataset becomes a one-line `StoreError` naming the path (exit 2).
    """
    try:
        with RunLease(store.root) as lease:
            lease.add(f"{p.stage.name}/{p.key}" for p in planned)
            lease.add(f"{ref.stage}/{ref.key}" for _, ref in (external or {}).values())
            return _execute(planned, config, dataset, store, external, on_stage, on_start)
    except OSError as err:
        raise disk_error(err, store.root) from err


def _execute(
    planned: Sequence[PlannedStage],
    config: BaseModel,
    dataset: DatasetSpec,
    store: ArtifactStore,
    external_in: Mapping[str, tuple[Stage, ArtifactRef]] | None,
    on_stage: Callable[[StageResult], None] | None,
    on_start: Callable[[PlannedStage], None] | None,
) -> RunResult:
    external = dict(external_in or {})
    for name, (_, ext) in external.items():
        # Looked up before the lease existed: make sure `gc` did not take it meanwhile.
        with store.lock(ext.stage, ext.key):
            if store.get(ext.stage, ext.key) is None:
                raise StoreError(
                    f"artifact {ext.stage}/{ext.key[:12]} ({name}) was removed while this run "
                    "started (by `sonarmap gc`?); run again"
                )
    outputs_of: dict[str, Stage] = {n: s for n, (s, _) in external.items()}
    refs: dict[str, ArtifactRef] = {n: r for n, (_, r) in external.items()}
    result = RunResult(dataset=str(dataset.path), store=str(store.root))
    versions = _software_versions()
    verified: set[tuple[str, str, str]] = set()  # each bound file is hashed once per run
    opened: dict[str, Any] = {}  # the dataset, opened once per run and config section
    done: dict[str, PlannedStage] = {}
    for item in planned:
        name = item.stage.name
        outputs_of[name] = item.stage
        t0 = time.perf_counter()
        if on_start is not None:
            on_start(item)
        ref = None
        if item.hit:
            # Under the key's lock: a `gc` that chose this artifact before our lease
            # existed removes it under the same lock, so we see it whole or not at all.
            with store.lock(name, item.key):
                ref = store.get(name, item.key)
        status = "hit"
        if ref is None:
            if item.reason == "forced":
                _discard(store, name, item.key)
            section = getattr(config, name)
            inputs = _bind_inputs(item, refs, outputs_of, dataset, config, verified, opened)
            manifest_extra = {
                "version": item.stage.version,
                "recipe": item.recipe,
                "config": item.recipe["config"],
                "inputs": {k: v for k, v in item.recipe["inputs"].items()},
                "input_artifacts": {
                    k: f"{outputs_of[Input.parse(k).stage].name}/{v}"
                    for k, v in item.recipe["inputs"].items()
                },
                "dataset_path": str(dataset.path),
                "software": versions,
            }
            log.info("computing %s (%s)", name, item.reason)
            with store.staging(name, item.key, manifest_extra) as slot:
                if slot.tmp is not None:  # not committed by another process meanwhile
                    slot.extra = _compute(
                        item, section, inputs, slot.tmp, refs, outputs_of, dataset
                    )
            ref = slot.committed()
            status = "computed" if slot.tmp is not None else "reused"
            del inputs
            release_memory()
        refs[name] = ref
        result.artifacts[name] = ref
        done[name] = item
        found = output_checks.check_stage(name, refs)
        fatal = next((message for message, is_fatal in found if is_fatal), None)
        if len(done) < len(planned) or fatal is not None:
            # Finished work is referenced now, not only at the end of the run.
            record_run(store, dataset, config, planned, external, done=done)
        warnings = tuple(message for message, is_fatal in found if not is_fatal)
        if fatal is not None:
            cause = f"; first sign: {result.warnings[0]}" if result.warnings else ""
            raise output_checks.EmptyMap(f"{display_path(dataset.path.name)}: {fatal}{cause}")
        result.warnings.extend(warnings)
        stage_result = StageResult(
            stage=name,
            key=item.key,
            status=status,
            seconds=round(time.perf_counter() - t0, 3),
            path=str(ref.path),
            reason=item.reason,
            warnings=warnings,
        )
        result.stages.append(stage_result)
        if on_stage is not None:
            on_stage(stage_result)
    record_run(store, dataset, config, planned, external)
    return result


def _discard(store: ArtifactStore, stage: str, key: str) -> None:
    """Move a forced artifact out of sight atomically, then delete it."""
    with store.lock(stage, key):
        path = store.artifact_dir(stage, key)
        if path.exists():
            trash = store.tmp_path(f"forced-{stage}")
            trash.parent.mkdir(parents=True, exist_ok=True)
            path.rename(trash)
            shutil.rmtree(trash, ignore_errors=True)
