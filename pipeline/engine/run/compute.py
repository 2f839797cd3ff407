"""Computing one planned stage: bind its inputs, run it, write its outputs.

The runner (`sonarmap.pipeline.engine.run.runner`) holds the store's lock and staging directory; what
happens inside that directory is here, so it can run in the runner's process or in a
worker process (`compute_in_worker`, spawned by `sonarmap.pipeline.engine.run.workers`) alike. The
same job gives the same files wherever it runs.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from sonarmap.pipeline.engine.errors import (
    ConfigError,
    InternalError,
    PipelineError,
    SourceError,
    StageFailed,
)
from sonarmap.pipeline.engine.hashing import changed_file, changed_while_read
from sonarmap.pipeline.engine.run.planned import DatasetSpec, PlannedStage
from sonarmap.pipeline.engine.store.artifact_store import ArtifactRef
from sonarmap.stages.base import (
    UNITS_INPUT,
    Input,
    Output,
    Stage,
    StageInputError,
    StageSettingsError,
)

__all__ = ["ComputeJob", "compute_in_worker", "job_sections", "not_opened", "run_job"]

_REASON_CHARS = 200
"""Most characters of a stage's refusal quoted in the error line."""


@dataclass(frozen=True)
class ComputeJob:
    """Everything a process needs to compute one miss into `tmp` (picklable when the
    stage's `run`, config model and the dataset opener are module-level)."""

    item: PlannedStage
    sections: Mapping[str, Any]
    """The config sections the stage reads: its own, `reads_sections`, the dataset's."""
    dataset: DatasetSpec
    refs: Mapping[str, ArtifactRef]
    outputs_of: Mapping[str, tuple[Output, ...]]
    """The outputs each upstream stage declares. Declarations only: a producer's `run`
    may be a closure (the training stage of `sonarmap.pipeline.training.model` is), and a job
    that carried it could not travel to a worker process."""
    tmp: Path
    units_root: Path | None = None
    """The store whose per-keyframe units a stage declaring `units` reads and adds to
    (None: no memo, the stage computes everything)."""


def job_sections(stage: Stage, config: BaseModel) -> dict[str, Any]:
    """The sections of `config` a `ComputeJob` of `stage` carries (the whole config is
    a model built at run time, which a worker process could not unpickle)."""
    names = [stage.name, *stage.reads_sections]
    if stage.reads_dataset and stage.dataset_section:
        names.append(stage.dataset_section)
    return {name: getattr(config, name) for name in names}


def not_opened(path: Path, _section: Any) -> Any:
    """The opener of a job whose stage does not read the dataset."""
    raise InternalError(f"{path}: opened by a stage that does not read the dataset")


def _output(stage: Stage, produced: tuple[Output, ...], item: Input) -> Output:
    output = next((o for o in produced if o.name == item.output), None)
    if output is None:
        raise ConfigError(f"stage {stage.name}: {item.stage} has no output '{item.output}'")
    return output


def _bind_inputs(
    job: ComputeJob, verified: set[tuple[str, str, str]], opened: dict[str, Any]
) -> dict[str, Any]:
    """The stage's `run` mapping: each input's value under its `Input.name`, and the
    sections it reads under "config.<section>". A json output with a `record` type is
    handed over as that record; a file it refuses is bad input naming that file.

    The dataset is opened by the graph's `open` once per process and config section
    (`opened`): the stages reading it there (keyframes, submaps) share what it has read."""
    stage, sections, dataset = job.item.stage, job.sections, job.dataset
    from sonarmap.pipeline.engine.store.codecs import (
        read_verified,  # pyarrow: only when a stage computes
    )

    inputs: dict[str, Any] = {f"config.{s}": sections[s] for s in stage.reads_sections}
    columns = dict(stage.input_columns)
    for name in stage.inputs:
        if name.is_dataset:
            section = sections[stage.dataset_section or stage.name]
            once = section.model_dump_json() if isinstance(section, BaseModel) else repr(section)
            if once not in opened:
                opened[once] = dataset.open(dataset.path, section)
            inputs[name.name] = opened[once]
            continue
        output = _output(stage, job.outputs_of[name.stage], name)
        value = read_verified(
            job.refs[name.stage], output, verified, columns.get(name), dataset.codecs
        )
        record = output.record_type
        if record is not None and value is not None:
            try:
                value = record.from_json(value)
            except ValueError as err:
                raise _rejected_input(StageInputError(name, str(err)), job) from err
        inputs[name.name] = value
    return inputs


def _rejected_input(err: StageInputError, job: ComputeJob) -> SourceError:
    """A stage's refusal of an input, naming the file behind it: the recording where the
    input is the recording or was read straight from it (an artifact of a stage that reads
    the dataset, such as the keyframes' images: what the user can fix is the recording),
    with the artifact file after it; else the artifact file (another recording's, a
    pinned model's)."""
    item = err.input
    reason = (err.reason.splitlines() or [""])[0]
    # The stage's first line, cut to a short prefix: the whole line stays a few hundred
    # characters whatever the stage put in it.
    reason = reason if len(reason) <= _REASON_CHARS else reason[:_REASON_CHARS] + "..."
    stage = job.item.stage.name
    if item.is_dataset:
        return SourceError(f"{job.dataset.path}: {reason} (input of stage {stage})")
    where = item.name
    from_recording = False
    if item.stage in job.refs and item.stage in job.outputs_of:
        output = next((o for o in job.outputs_of[item.stage] if o.name == item.output), None)
        ref = job.refs[item.stage]
        filename = output.filename if output is not None else item.output
        where = f"{ref.stage}/{ref.key}/{filename}"
        recipe = ref.manifest.get("recipe")
        read = recipe.get("dataset") if isinstance(recipe, dict) else None
        from_recording = read is not None and read == job.dataset.fingerprint
        if from_recording:
            where = f"{ref.stage}/{ref.key[:12]}/{filename}"
    if from_recording:
        return SourceError(f"{job.dataset.path}: {reason} (input of stage {stage}: {where})")
    return SourceError(f"{where}: {reason} (input of stage {stage})")


def run_job(
    job: ComputeJob, verified: set[tuple[str, str, str]], opened: dict[str, Any]
) -> dict[str, Any]:
    """Bind, run the stage and write its outputs into `job.tmp`; the manifest's extra
    fields.

    A `StageInputError` becomes bad input (exit 2) naming the file behind the input;
    any other exception of the stage is a `StageFailed` (exit 1).
    """
    from sonarmap.pipeline.engine.store.codecs import write_output
    from sonarmap.pipeline.engine.store.units import UnitMemo

    stage = job.item.stage
    inputs = _bind_inputs(job, verified, opened)
    memo = None
    if stage.units and job.units_root is not None:
        dataset = job.dataset.fingerprint if stage.reads_dataset else ""
        forced = job.item.reason == "forced"  # recomputed from scratch, units too
        identity = job.dataset.identity if stage.reads_dataset else ()
        memo = UnitMemo(job.units_root, stage.name, dataset, not forced, identity)
        inputs[UNITS_INPUT] = memo
    provenance = {"stage": stage.name, "version": str(stage.version), "key": job.item.key}
    try:
        values = stage.run(job.sections[stage.name], inputs)
        del inputs
        facts: dict[str, Any] = {}
        for output in stage.outputs:
            value = values.get(output.name)
            if value is None:
                if not output.optional:
                    raise StageFailed(f"stage {stage.name}: output '{output.name}' missing")
                continue
            facts[output.name] = write_output(
                job.tmp, stage.name, output, value, provenance, job.dataset.codecs
            )
        # After the outputs: a lazy one (the keyframes' images) reads the recording there.
        if stage.reads_dataset and (changed := changed_file(job.dataset.identity)):
            raise changed_while_read(changed)  # what was read is not what the key names
    except (PipelineError, OSError):
        raise  # OSError: a full or read-only disk, reported by `execute` (exit 2)
    except StageInputError as err:
        raise _rejected_input(err, job) from err
    except StageSettingsError as err:
        raise ConfigError(f"stage {stage.name}: {err}") from err
    except Exception as err:
        raise StageFailed(f"stage {stage.name} failed: {type(err).__name__}: {err}") from err
    return {"outputs": facts, **(memo.manifest_fields() if memo is not None else {})}


def compute_in_worker(job: ComputeJob) -> dict[str, Any]:
    """`run_job` in a worker process: its own verified files and opened dataset."""
    from sonarmap.stages.kernels.parallel import release_memory

    try:
        return run_job(job, set(), {})
    finally:
        release_memory()
