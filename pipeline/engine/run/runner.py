"""The runner: compute a plan's misses, side by side where the graph allows, and commit them.

The plan (from `sonarmap.pipeline.engine.run.planner`) is a graph: a stage starts as soon as the
stages it reads have committed, up to `workers` at a time (`sonarmap.pipeline.engine.run.workers`:
one in this process, the others in spawned worker processes). Each miss is computed
under its key's lock in the store (`sonarmap.pipeline.engine.run.compute` binds the upstream
artifacts and the dataset, calls the stage and writes its outputs); the runner commits
it atomically. Stages are pure functions of their inputs, so the artifacts and their
bytes do not depend on the number of workers or the order stages finish in.
"""

from __future__ import annotations

import functools
import logging
import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass, field, replace
from importlib import metadata
from typing import Any

from pydantic import BaseModel

from sonarmap.pipeline.engine.errors import StoreError
from sonarmap.pipeline.engine.run import output_checks
from sonarmap.pipeline.engine.run.abandon import while_open
from sonarmap.pipeline.engine.run.compute import ComputeJob, job_sections, not_opened
from sonarmap.pipeline.engine.run.planned import DatasetSpec, PlannedStage
from sonarmap.pipeline.engine.run.planner import plan
from sonarmap.pipeline.engine.run.run_records import record_run
from sonarmap.pipeline.engine.run.workers import Slots
from sonarmap.pipeline.engine.store.artifact_store import ArtifactRef, ArtifactStore
from sonarmap.pipeline.engine.store.commit_gate import CommitGate
from sonarmap.pipeline.engine.store.disk import discard_artifact, disk_error
from sonarmap.pipeline.engine.store.leases import RunLease
from sonarmap.pipeline.engine.text import display_path
from sonarmap.stages.base import Input, Stage

__all__ = ["DatasetSpec", "PlannedStage", "RunResult", "StageResult", "execute", "plan"]

log = logging.getLogger(__name__)
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
    units: tuple[int, int] | None = None
    """A stage computed from per-keyframe work units: (reused, computed) units."""


@dataclass
class RunResult:
    dataset: str
    store: str
    stages: list[StageResult] = field(default_factory=list)
    artifacts: dict[str, ArtifactRef] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    """Empty or collapsed outputs (`sonarmap.pipeline.engine.run.output_checks`), one line each."""

    def to_json(self) -> dict[str, Any]:
        return {
            "dataset": self.dataset,
            "store": self.store,
            "stages": [r.__dict__ for r in self.stages],
            "warnings": list(self.warnings),
        }


@functools.cache
def _software_versions() -> dict[str, str]:
    """Versions of the libraries a manifest records (read once, when a stage computes:
    a fully cached run never scans the installed distributions)."""
    versions = {}
    for name in _VERSIONED:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return versions


def execute(
    planned: Sequence[PlannedStage],
    config: BaseModel,
    dataset: DatasetSpec,
    store: ArtifactStore,
    *,
    external: Mapping[str, tuple[Stage, ArtifactRef]] | None = None,
    on_stage: Callable[[StageResult], None] | None = None,
    on_start: Callable[[PlannedStage], None] | None = None,
    workers: int = 1,
) -> RunResult:
    """Compute the misses and commit them; hits are only looked up.

    `workers`: stages computed at the same time (1: one after another, in plan order;
    `sonarmap.pipeline.api.run_dataset` passes the cores unless told otherwise). On the first error no further stage starts;
    the running ones finish (their artifacts are committed) and the error is raised.

    While it runs, a lease on the store holds every planned and external address, so
    `gc` leaves them alone; the run record is rewritten as each stage commits, so an
    interrupted run's finished stages stay referenced. Any OSError from the store or
    the dataset becomes a one-line `StoreError` naming the path (exit 2).
    """
    try:
        with RunLease(store.root) as lease, while_open(lease.release):
            lease.add(f"{p.stage.name}/{p.key}" for p in planned)
            lease.add(f"{ref.stage}/{ref.key}" for _, ref in (external or {}).values())
            return _execute(planned, config, dataset, store, external, on_stage, on_start, workers)
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
    workers: int,
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
    outputs_of.update((item.stage.name, item.stage) for item in planned)
    refs: dict[str, ArtifactRef] = {n: r for n, (_, r) in external.items()}
    result = RunResult(dataset=str(dataset.path), store=str(store.root))
    done: dict[str, PlannedStage] = {}
    finished: dict[str, StageResult] = {}
    order = {item.stage.name: i for i, item in enumerate(planned)}
    gate = CommitGate()

    def produce(item: PlannedStage, slots: Slots) -> tuple[ArtifactRef, str]:
        """The stage's artifact: looked up (a hit), or computed and committed."""
        name = item.stage.name
        if item.hit:
            # Under the key's lock: a `gc` that chose this artifact before our lease
            # existed removes it under the same lock, so we see it whole or not at all.
            with store.lock(name, item.key):
                ref = store.get(name, item.key)
            if ref is not None:
                return ref, "hit"
        if item.reason == "forced":
            discard_artifact(store, name, item.key)
        manifest_extra = {
            "version": item.stage.version,
            "recipe": item.recipe,
            "config": item.recipe["config"],
            "inputs": dict(item.recipe["inputs"].items()),
            "input_artifacts": {
                k: f"{outputs_of[Input.parse(k).stage].name}/{v}"
                for k, v in item.recipe["inputs"].items()
            },
            "dataset_path": str(dataset.path),
            "software": dict(_software_versions()),
        }
        log.info("computing %s (%s)", name, item.reason)
        upstream = {n: refs[n] for n in item.stage.upstream}
        # Only the stage reading the dataset carries the graph's opener, so the others
        # can travel to a worker process whatever the opener is (a test's lambda).
        spec = dataset if item.stage.reads_dataset else replace(dataset, open=not_opened)
        with store.staging(name, item.key, manifest_extra, gate) as slot:
            if slot.tmp is not None:  # not committed by another process meanwhile
                sections = job_sections(item.stage, config)
                produced = {n: outputs_of[n].outputs for n in item.stage.upstream}
                job = ComputeJob(item, sections, spec, upstream, produced, slot.tmp, store.root)
                slot.extra = slots.compute(job)
        return slot.committed(), "computed" if slot.tmp is not None else "reused"

    def commit(item: PlannedStage, ref: ArtifactRef, status: str, seconds: float) -> None:
        name = item.stage.name
        refs[name] = ref
        done[name] = item
        found = output_checks.check_stage(name, refs)
        fatal = next((message for message, is_fatal in found if is_fatal), None)
        if (len(done) < len(planned) and status != "hit") or fatal is not None:
            # Finished work is referenced now, not only at the end of the run. A hit
            # needs no early record: it was there before the run, and the next computed
            # stage's record (or the final one) names it with the rest.
            record_run(store, dataset, config, planned, external, done=done)
        warnings = tuple(message for message, is_fatal in found if not is_fatal)
        if name == "keyframes":
            cached = status != "computed"
            warnings += tuple(output_checks.recording_warnings(ref, cached, str(dataset.path)))
        units = None
        if status == "computed" and "units" in ref.manifest:
            units = (int(ref.manifest["units_reused"]), int(ref.manifest["units_computed"]))
            warnings += tuple(str(w) for w in ref.manifest.get("unit_warnings") or ())
        if fatal is not None:
            cause = f"; first sign: {result.warnings[0]}" if result.warnings else ""
            raise output_checks.EmptyMap(f"{display_path(dataset.path.name)}: {fatal}{cause}")
        result.warnings.extend(warnings)
        finished[name] = StageResult(
            stage=name,
            key=item.key,
            status=status,
            seconds=round(seconds, 3),
            path=str(ref.path),
            reason=item.reason,
            warnings=warnings,
            units=units,
        )
        if on_stage is not None:
            on_stage(finished[name])

    waiting = list(planned)
    started: dict[str, float] = {}
    running: dict[Future[tuple[ArtifactRef, str]], PlannedStage] = {}
    failure: BaseException | None = None
    close = functools.partial(
        _close_interrupted, gate, store, dataset, config, planned, external, done
    )
    try:
        with while_open(close):  # closed from the main thread if this one is left behind
            failure = _run_all(
                waiting, running, started, refs, order, produce, commit, on_start, workers
            )
            if failure is None:
                record_run(store, dataset, config, planned, external)
    except (KeyboardInterrupt, SystemExit):
        close()
        raise
    if failure is not None:
        raise failure
    for item in planned:  # plan order, whatever order the stages finished in
        result.artifacts[item.stage.name] = refs[item.stage.name]
        result.stages.append(finished[item.stage.name])
    return result


def _run_all(
    waiting: list[PlannedStage],
    running: dict[Future[tuple[ArtifactRef, str]], PlannedStage],
    started: dict[str, float],
    refs: Mapping[str, ArtifactRef],
    order: Mapping[str, int],
    produce: Callable[[PlannedStage, Slots], tuple[ArtifactRef, str]],
    commit: Callable[[PlannedStage, ArtifactRef, str, float], None],
    on_start: Callable[[PlannedStage], None] | None,
    workers: int,
) -> BaseException | None:
    """Start every stage when its inputs are ready, commit each as it ends; the first
    error, once every running stage has stopped."""
    failure: BaseException | None = None
    with Slots(workers) as slots:
        while True:
            # Start every stage whose inputs are ready, in plan order, while slots are free.
            for item in list(waiting):
                if failure is not None or len(running) >= slots.workers:
                    break
                if not all(u in refs for u in item.stage.upstream):
                    continue
                waiting.remove(item)
                started[item.stage.name] = time.perf_counter()
                if on_start is not None:
                    on_start(item)
                running[slots.submit(functools.partial(produce, item, slots))] = item
            if not running:
                break
            ready, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in sorted(ready, key=lambda f: order[running[f].stage.name]):
                item = running.pop(future)
                try:
                    ref, status = future.result()
                    seconds = time.perf_counter() - started[item.stage.name]
                    commit(item, ref, status, seconds)
                except BaseException as err:  # the first error is reported, once all stop
                    failure = failure or err
    return failure


def _close_interrupted(
    gate: CommitGate,
    store: ArtifactStore,
    dataset: DatasetSpec,
    config: BaseModel,
    planned: Sequence[PlannedStage],
    external: Mapping[str, tuple[Stage, ArtifactRef]],
    done: dict[str, PlannedStage],
) -> None:
    """Ctrl-C or SIGTERM: no stage commits from now on; one that committed before the
    interrupt reached this thread enters the run record (else the next `gc` would take
    it), and the temporary folders of the stages still computing go."""
    committed, staging = gate.close()
    by_address = {(p.stage.name, p.key): p for p in planned}
    done.update((a[0], by_address[a]) for a in committed if a in by_address)
    if done:  # the last stage's commit waits for the final record, which did not come
        record_run(store, dataset, config, planned, external, done=done)
    for tmp in staging:
        shutil.rmtree(tmp, ignore_errors=True)
