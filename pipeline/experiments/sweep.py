"""Sweeps: the cross product of datasets and override values through the stage graph.

Artifacts shared between runs (same key) are computed once: all runs share one store, and
the per-key lock makes a second worker wait and reuse. A failed run does not stop the others.
Executors: a local process pool, or Ray tasks (a local instance unless an address is given;
the store on a shared filesystem). A run's stages go one at a time: the points run in parallel.
"""

from __future__ import annotations

import itertools
import logging
import os
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sonarmap.pipeline.engine.errors import ConfigError, PipelineError
from sonarmap.pipeline.engine.run.worker_life import die_with_parent, end_pool
from sonarmap.pipeline.experiments.headline_columns import (
    frame_of,
    headline_columns,
    headline_header,
    shared_frame,
)
from sonarmap.pipeline.experiments.submap_columns import submap_columns
from sonarmap.pipeline.experiments.sweep_grid import sweep_axes

__all__ = [
    "ALL_STRUCTURE",
    "METRIC_COLUMNS",
    "PILING_CLASSES",
    "RunOutcome",
    "RunSpec",
    "class_value",
    "expand",
    "group_label",
    "per_class",
    "run_sweep",
    "stage_path",
    "sweep_tables",
]

if TYPE_CHECKING:
    from sonarmap.pipeline.engine.run.graph import Graph

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunSpec:
    dataset: str
    overrides: tuple[tuple[str, str], ...]
    base_overrides: tuple[str, ...] = ()
    config_path: str | None = None
    store: str = "data/store"
    protocol: str | None = None
    """A name for the config this run belongs to (`sonarmap study` compares several)."""
    figures: bool = True

    @property
    def override_args(self) -> list[str]:
        return [*self.base_overrides, *(f"{k}={v}" for k, v in self.overrides)]


@dataclass
class RunOutcome:
    dataset: str
    overrides: dict[str, str]
    status: str
    seconds: float
    summary: dict[str, Any] = field(default_factory=dict)
    stages: list[dict[str, Any]] = field(default_factory=list)
    error: str | None = None
    protocol: str | None = None
    config_path: str | None = None
    exit_code: int = 0
    """0 when the run succeeded; 2 when it failed on bad input, 1 on a bug."""

    def stage_path(self, stage: str) -> Path | None:
        """The artifact directory of `stage` in this run (None when it did not run)."""
        return stage_path(self.stages, stage)

    def to_json(self) -> dict[str, Any]:
        return dict(self.__dict__)


def stage_path(stages: Sequence[Mapping[str, Any]], stage: str) -> Path | None:
    """The artifact directory of `stage` among a run's `stages` (as in `run --json`)."""
    for s in stages:
        if s.get("stage") == stage and s.get("path"):
            return Path(str(s["path"]))
    return None


def expand(
    datasets: Sequence[Path],
    sweep_sets: Sequence[str],
    *,
    base_overrides: Sequence[str] = (),
    config_path: Path | None = None,
    store: Path = Path("data/store"),
    protocol: str | None = None,
    is_list_key: Callable[[str], bool] = lambda key: False,
    figures: bool = True,
) -> list[RunSpec]:
    """Cross product: every dataset x every combination of `key=v1,v2,...` values (no
    point twice: `sweep_axes`; a list setting's points in brackets)."""
    axes = sweep_axes(datasets, sweep_sets, base_overrides, is_list_key)
    combos = list(itertools.product(*axes)) if axes else [()]
    return [
        RunSpec(
            dataset=str(Path(d).resolve()),
            overrides=tuple(combo),
            base_overrides=tuple(base_overrides),
            config_path=str(config_path) if config_path else None,
            store=str(Path(store).resolve()),
            protocol=protocol,
            figures=figures,
        )
        for d in datasets
        for combo in combos
    ]


def run_one(spec: RunSpec, graph: Graph | None = None) -> RunOutcome:
    """Run one point through `graph` (None: the real pipeline); a failure is its outcome."""
    from sonarmap.pipeline.api import RunRequest, run_dataset

    t0 = time.perf_counter()
    overrides = dict(spec.overrides)
    tags: dict[str, Any] = {"protocol": spec.protocol, "config_path": spec.config_path}
    try:
        result, summary = run_dataset(
            RunRequest(
                Path(spec.dataset),
                config_path=Path(spec.config_path) if spec.config_path else None,
                overrides=spec.override_args,
                store_dir=Path(spec.store),
                workers=1,
                figures=spec.figures,
            ),
            graph,
        )
    except Exception as err:  # a failed run must not stop the sweep
        log.debug("sweep run failed", exc_info=True)
        error, code = _failure(err)
        seconds = time.perf_counter() - t0
        return RunOutcome(
            spec.dataset, overrides, "failed", seconds, error=error, exit_code=code, **tags
        )
    stages = [dict(s.__dict__) for s in result.stages]
    return RunOutcome(
        spec.dataset, overrides, "ok", round(time.perf_counter() - t0, 3), summary, stages, **tags
    )


def _failure(err: Exception) -> tuple[str, int]:
    """A failed run's message and exit status: 2 for bad input (a `PipelineError` of
    code 2, an OSError naming its file: as in `sonarmap run`), 1 for a bug."""
    if isinstance(err, PipelineError):
        return str(err), err.exit_code
    if isinstance(err, OSError) and err.filename is not None:
        return f"{err.filename}: {err.strerror}", 2
    return f"{type(err).__name__}: {err}", 1


def _run_in_pool(spec: RunSpec, graph: Graph | None) -> RunOutcome:
    """`run_one` in a pool worker (forked: it has the command's signal handlers). Ctrl-C or
    SIGTERM unwinds the run (its lease released, its commits closed), then ends the
    worker: the pool would take the exception as the run's result and start the next."""
    try:
        return run_one(spec, graph)
    except KeyboardInterrupt:
        os._exit(130)
    except SystemExit as stop:
        os._exit(stop.code if isinstance(stop.code, int) else 1)


def _local(
    specs: Sequence[RunSpec], jobs: int, done: Callable[[RunOutcome], None], graph: Graph | None
) -> list[RunOutcome]:
    if jobs <= 1:
        outcomes = []
        for s in specs:
            outcomes.append(run_one(s, graph))
            done(outcomes[-1])
        return outcomes
    results: dict[int, RunOutcome] = {}
    # Linux forks every worker up front: never more than there are runs.
    pool = ProcessPoolExecutor(
        max_workers=min(jobs, len(specs)), initializer=die_with_parent, initargs=(os.getpid(),)
    )
    futures = {pool.submit(_run_in_pool, s, graph): i for i, s in enumerate(specs)}
    try:
        for fut in as_completed(futures):
            results[futures[fut]] = fut.result()
            done(results[futures[fut]])
    except BaseException:
        # Ctrl-C or SIGTERM: a pool's shutdown would wait for every queued run. Those start
        # no more, the running ones end (each unwound as by its own Ctrl-C), and the runs
        # that finished meanwhile are still reported.
        end_pool(pool)
        for fut, i in futures.items():
            if i not in results and fut.done() and not fut.cancelled() and not fut.exception():
                results[i] = fut.result()
                done(results[i])
        raise
    pool.shutdown(wait=True)
    return [results[i] for i in range(len(specs))]


def run_sweep(
    specs: Sequence[RunSpec],
    *,
    executor: str = "local",
    jobs: int = 1,
    address: str | None = None,
    on_done: Callable[[RunOutcome], None] | None = None,
    graph: Graph | None = None,
) -> list[RunOutcome]:
    """Execute every run through `graph` (None: the real pipeline; each worker gets it
    with its run); outcomes in the order of `specs`."""
    done = on_done or (lambda _o: None)
    if executor == "local":
        return _local(specs, jobs, done, graph)
    if executor == "ray":
        from sonarmap.pipeline.experiments.sweep_ray import run_on_ray

        return run_on_ray(specs, jobs, address, done, graph, run_one)
    raise ConfigError(f"--executor {executor}: expected 'local' or 'ray'")


PILING_CLASSES: tuple[str, ...] = ("cylindrical_piling", "rectangular_piling")
"""The classes the paper infers in simulation (its Section V); summed as `..._piling_...`."""

ALL_STRUCTURE = "all_structure"
"""The per-class aggregate of every class but the seafloor (`metrics.per_class.classes`)."""


def per_class(summary: Mapping[str, Any]) -> dict[str, Any]:
    """`summary.metrics.per_class.classes` ({} when the evaluate stage did not report it)."""
    metrics = summary.get("metrics") or {}
    classes = (metrics.get("per_class") or {}).get("classes") or {}
    return dict(classes)


def class_value(
    classes: Mapping[str, Any], names: Sequence[str], part: str, name: str
) -> float | None:
    """Sum of `classes[c][part][name]` over the classes `names` present (None if none is)."""
    values = [((classes.get(c) or {}).get(part) or {}).get(name) for c in names if c in classes]
    found = [float(v) for v in values if v is not None]
    return sum(found) if found else None


def _ratio(num: float | int | None, den: float | int | None) -> float | None:
    return float(num) / float(den) if num is not None and den else None


def _flat(summary: Mapping[str, Any]) -> dict[str, float | int | None]:
    """One run's figures as flat columns; every key is always present (None when absent)."""
    voxels = summary.get("voxels") or {}
    metrics = summary.get("metrics") or {}
    errors = metrics.get("errors") or {}
    completeness = metrics.get("completeness") or {}
    trajectory = metrics.get("trajectory") or {}
    classes = per_class(summary)
    row: dict[str, float | int | None] = {
        "voxels_standard": voxels.get("standard"),
        "voxels_semantic": voxels.get("semantic"),
        "ratio": _ratio(voxels.get("semantic"), voxels.get("standard")),
        **headline_columns(summary),
        "median_error_standard_m": (errors.get("standard") or {}).get("median_m"),
        "median_error_semantic_m": (errors.get("semantic") or {}).get("median_m"),
        "median_error_inferred_m": (errors.get("inferred") or {}).get("median_m"),
        "completeness_standard": completeness.get("standard"),
        "completeness_semantic": completeness.get("semantic"),
        "slam_ate_m": trajectory.get("slam_ate_m"),
    }
    for map_name in ("standard", "semantic"):
        row[f"accurate_voxels_{map_name}"] = class_value(
            classes, (ALL_STRUCTURE,), map_name, "accurate_voxels"
        )
    row["accurate_ratio"] = _ratio(row["accurate_voxels_semantic"], row["accurate_voxels_standard"])
    for map_name in ("standard", "semantic"):
        row[f"accurate_voxels_piling_{map_name}"] = class_value(
            classes, PILING_CLASSES, map_name, "accurate_voxels"
        )
    for map_name in ("standard", "semantic"):
        row[f"completeness_all_{map_name}"] = class_value(
            classes, (ALL_STRUCTURE,), map_name, "completeness"
        )
    row.update(submap_columns(summary))
    return row


METRIC_COLUMNS: tuple[str, ...] = ("seconds", *_flat({}))
"""The numeric per-run columns of sweep.parquet, in order."""


def group_label(group: Mapping[str, Any]) -> str:
    """`protocol: k=v, ...` of a group (protocol only when the sweep has one)."""
    label = ", ".join(f"{k}={v}" for k, v in group["overrides"].items()) or "(defaults)"
    return f"{group['protocol']}: {label}" if group.get("protocol") else label


def sweep_tables(outcomes: Sequence[RunOutcome]) -> tuple[Any, list[dict[str, Any]], str]:
    """(pyarrow table one row per run, groups with mean/std, markdown of the groups).

    Runs are grouped by (protocol, overrides), in the order they first appear (the order
    the values were given: sorted as text, 11 came before 5). Markdown leaves out the
    columns no run reported, and gives no spread for a group of one run.
    """
    import json

    import numpy as np
    import pyarrow as pa

    rows: list[dict[str, Any]] = []
    for o in outcomes:
        flat = _flat(o.summary)
        rows.append(
            {
                "dataset": o.dataset,
                "protocol": o.protocol,
                "overrides": json.dumps(o.overrides, sort_keys=True),
                "status": o.status,
                "error": o.error,
                "headline_frame": frame_of(o.summary) if o.status == "ok" else None,
                "seconds": float(o.seconds),
                **{k: (None if v is None else float(v)) for k, v in flat.items()},
            }
        )
    schema = pa.schema(
        [
            ("dataset", pa.string()),
            ("protocol", pa.string()),
            ("overrides", pa.string()),
            ("status", pa.string()),
            ("error", pa.string()),
            ("headline_frame", pa.string()),
            *((m, pa.float64()) for m in METRIC_COLUMNS),
        ]
    )
    table = pa.Table.from_pylist(rows, schema=schema)
    protocols = list(dict.fromkeys(r["protocol"] for r in rows))
    groups = []
    for protocol in protocols:
        for key in dict.fromkeys(r["overrides"] for r in rows if r["protocol"] == protocol):
            members = [
                r
                for r in rows
                if r["protocol"] == protocol and r["overrides"] == key and r["status"] == "ok"
            ]
            group: dict[str, Any] = {
                "overrides": json.loads(key),
                "runs": len(members),
                "headline_frame": shared_frame(r["headline_frame"] for r in members),
            }
            if protocol is not None:
                group["protocol"] = protocol
            for m in METRIC_COLUMNS:
                vals = np.array([r[m] for r in members if r.get(m) is not None], dtype=float)
                group[m] = {
                    "mean": float(vals.mean()) if vals.size else None,
                    "std": float(vals.std(ddof=1))
                    if vals.size > 1
                    else (0.0 if vals.size else None),
                }
            groups.append(group)
    shown = [m for m in METRIC_COLUMNS if any(g[m]["mean"] is not None for g in groups)]
    frame = shared_frame(g["headline_frame"] for g in groups)
    header = ["overrides", "runs", *(headline_header(m, frame) for m in shown)]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for g in groups:
        cells = [group_label(g), str(g["runs"])]
        for m in shown:
            mean, std = g[m]["mean"], g[m]["std"]
            spread = f" ± {std:.2g}" if g["runs"] > 1 else ""
            cells.append("-" if mean is None else f"{mean:.4g}{spread}")
        lines.append("| " + " | ".join(cells) + " |")
    return table, groups, "\n".join(lines) + "\n"
