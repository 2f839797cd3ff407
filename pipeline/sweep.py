"""Sweeps: the cross product of datasets and override values through the stage graph.

Artifacts shared between runs (same key) are computed once: every run goes through
the same store, and the per-key lock makes a second worker wait and reuse. A failed
run is reported and does not stop the others. Executors: a local process pool, or
Ray tasks (a local instance is started when no address is given); with Ray the store
must be a path every worker can reach (a shared filesystem).
"""

from __future__ import annotations

import itertools
import logging
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.errors import ConfigError, PipelineError

__all__ = ["RunSpec", "expand", "run_sweep", "sweep_tables"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunSpec:
    dataset: str
    overrides: tuple[tuple[str, str], ...]
    base_overrides: tuple[str, ...] = ()
    config_path: str | None = None
    store: str = "data/store"

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

    def to_json(self) -> dict[str, Any]:
        return dict(self.__dict__)


def expand(
    datasets: Sequence[Path],
    sweep_sets: Sequence[str],
    *,
    base_overrides: Sequence[str] = (),
    config_path: Path | None = None,
    store: Path = Path("data/store"),
) -> list[RunSpec]:
    """Cross product: every dataset x every combination of `key=v1,v2,...` values."""
    axes: list[list[tuple[str, str]]] = []
    for text in sweep_sets:
        key, sep, values = text.partition("=")
        if not sep or not values:
            raise ConfigError(f"--set '{text}': expected section.field=v1,v2,...")
        axes.append([(key.strip(), v.strip()) for v in values.split(",") if v.strip()])
    combos = list(itertools.product(*axes)) if axes else [()]
    return [
        RunSpec(
            dataset=str(Path(d).resolve()),
            overrides=tuple(combo),
            base_overrides=tuple(base_overrides),
            config_path=str(config_path) if config_path else None,
            store=str(Path(store).resolve()),
        )
        for d in datasets
        for combo in combos
    ]


def run_one(spec: RunSpec) -> RunOutcome:
    """Run one sweep point; never raises (failures become a failed outcome)."""
    from pipeline.api import run_dataset

    t0 = time.perf_counter()
    overrides = dict(spec.overrides)
    try:
        result, summary = run_dataset(
            Path(spec.dataset),
            config_path=Path(spec.config_path) if spec.config_path else None,
            overrides=spec.override_args,
            store_dir=Path(spec.store),
        )
    except PipelineError as err:
        return RunOutcome(
            spec.dataset, overrides, "failed", time.perf_counter() - t0, error=str(err)
        )
    except Exception as err:  # a bug in one run must not stop the sweep
        log.debug("sweep run failed", exc_info=True)
        msg = f"{type(err).__name__}: {err}"
        return RunOutcome(spec.dataset, overrides, "failed", time.perf_counter() - t0, error=msg)
    stages = [s.__dict__ for s in result.stages]
    return RunOutcome(
        spec.dataset, overrides, "ok", round(time.perf_counter() - t0, 3), summary, stages
    )


def _local(
    specs: Sequence[RunSpec], jobs: int, done: Callable[[RunOutcome], None]
) -> list[RunOutcome]:
    if jobs <= 1:
        outcomes = []
        for s in specs:
            outcomes.append(run_one(s))
            done(outcomes[-1])
        return outcomes
    results: dict[int, RunOutcome] = {}
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = {pool.submit(run_one, s): i for i, s in enumerate(specs)}
        for fut in as_completed(futures):
            results[futures[fut]] = fut.result()
            done(results[futures[fut]])
    return [results[i] for i in range(len(specs))]


def _ray(
    specs: Sequence[RunSpec], jobs: int, address: str | None, done: Callable[[RunOutcome], None]
) -> list[RunOutcome]:
    try:
        import ray
    except ImportError as err:
        raise ConfigError(
            "--executor ray needs the 'ray' package (pip install 'sonarmap[ray]')"
        ) from err
    env = {
        k: v
        for k, v in os.environ.items()
        if k in ("PYTHONPATH", "SONARMAP_GRAPH", "OMP_NUM_THREADS")
    }
    started = False
    if not ray.is_initialized():
        kwargs: dict[str, Any] = {
            "include_dashboard": False,
            "log_to_driver": False,
            "runtime_env": {"env_vars": env},
        }
        if address:
            ray.init(address=address, **kwargs)
        else:
            ray.init(num_cpus=max(jobs, 1), **kwargs)
        started = True
    try:
        remote = ray.remote(num_cpus=1)(run_one)
        pending = {remote.remote(s): i for i, s in enumerate(specs)}
        results: dict[int, RunOutcome] = {}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                i = pending.pop(ref)
                results[i] = ray.get(ref)
                done(results[i])
        return [results[i] for i in range(len(specs))]
    finally:
        if started:
            ray.shutdown()


def run_sweep(
    specs: Sequence[RunSpec],
    *,
    executor: str = "local",
    jobs: int = 1,
    address: str | None = None,
    on_done: Callable[[RunOutcome], None] | None = None,
) -> list[RunOutcome]:
    """Execute every run; outcomes in the order of `specs`."""
    done = on_done or (lambda _o: None)
    if executor == "local":
        return _local(specs, jobs, done)
    if executor == "ray":
        return _ray(specs, jobs, address, done)
    raise ConfigError(f"--executor {executor}: expected 'local' or 'ray'")


def _flat(summary: dict[str, Any]) -> dict[str, float | int | None]:
    voxels = summary.get("voxels") or {}
    metrics = summary.get("metrics") or {}
    errors = metrics.get("errors") or {}
    completeness = metrics.get("completeness") or {}
    trajectory = metrics.get("trajectory") or {}
    row: dict[str, float | int | None] = {
        "voxels_standard": voxels.get("standard"),
        "voxels_semantic": voxels.get("semantic"),
        "median_error_standard_m": (errors.get("standard") or {}).get("median_m"),
        "median_error_semantic_m": (errors.get("semantic") or {}).get("median_m"),
        "completeness_standard": completeness.get("standard"),
        "completeness_semantic": completeness.get("semantic"),
        "slam_ate_m": trajectory.get("slam_ate_m"),
    }
    if row["voxels_standard"] and row["voxels_semantic"] is not None:
        row["ratio"] = float(row["voxels_semantic"]) / float(row["voxels_standard"])
    return row


def sweep_tables(outcomes: Sequence[RunOutcome]) -> tuple[Any, list[dict[str, Any]], str]:
    """(pyarrow table one row per run, groups with mean/std, markdown of the groups)."""
    import json

    import numpy as np
    import pyarrow as pa

    rows: list[dict[str, Any]] = []
    for o in outcomes:
        rows.append(
            {
                "dataset": o.dataset,
                "overrides": json.dumps(o.overrides, sort_keys=True),
                "status": o.status,
                "seconds": float(o.seconds),
                "error": o.error,
                **{k: (None if v is None else float(v)) for k, v in _flat(o.summary).items()},
            }
        )
    table = pa.Table.from_pylist(rows)
    metrics = [
        k for k in (rows[0] if rows else {}) if k not in ("dataset", "overrides", "status", "error")
    ]
    groups = []
    for key in sorted({r["overrides"] for r in rows}):
        members = [r for r in rows if r["overrides"] == key and r["status"] == "ok"]
        group: dict[str, Any] = {"overrides": json.loads(key), "runs": len(members)}
        for m in metrics:
            vals = np.array([r[m] for r in members if r.get(m) is not None], dtype=float)
            group[m] = {
                "mean": float(vals.mean()) if vals.size else None,
                "std": float(vals.std(ddof=1)) if vals.size > 1 else (0.0 if vals.size else None),
            }
        groups.append(group)
    lines = [
        "| overrides | runs | " + " | ".join(metrics) + " |",
        "|---|---|" + "---|" * len(metrics),
    ]
    for g in groups:
        cells = []
        for m in metrics:
            mean, std = g[m]["mean"], g[m]["std"]
            cells.append("-" if mean is None else f"{mean:.4g} ± {std:.2g}")
        label = ", ".join(f"{k}={v}" for k, v in g["overrides"].items()) or "(defaults)"
        lines.append(f"| {label} | {g['runs']} | " + " | ".join(cells) + " |")
    return table, groups, "\n".join(lines) + "\n"
