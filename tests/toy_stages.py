"""Toy stages for the engine's contract tests (also run in subprocesses)."""

from __future__ import annotations

import os
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.pipeline.engine.run.graph import Graph
from sonarmap.stages.base import DATASET, Input, Output, Stage, StageConfig

CALLS: Counter[str] = Counter()


class SourceConfig(StageConfig):
    scale: float = 1.0
    n_rows: int = 50


class DoubleConfig(StageConfig):
    factor: int = 2
    sleep_s: float = 0.0


class SummaryConfig(StageConfig):
    label: str = "sum"
    fail: bool = False


class CountConfig(StageConfig):
    bins: int = 4


def _mark(name: str) -> None:
    CALLS[name] += 1
    log = os.environ.get("TOY_CALL_LOG")
    if log:
        with Path(log).open("a") as f:
            f.write(f"{name} {os.getpid()}\n")


def _source(config: SourceConfig, inputs: dict[str, Any]) -> dict[str, Any]:
    _mark("source")
    data = np.frombuffer(inputs["dataset"], dtype=np.uint8)[: config.n_rows].astype(np.float64)
    return {
        "table": pa.table({"i": np.arange(len(data), dtype=np.int64), "v": data * config.scale})
    }


def _double(config: DoubleConfig, inputs: dict[str, Any]) -> dict[str, Any]:
    _mark("double")
    time.sleep(config.sleep_s)
    _hold("double")
    t = inputs["source.table"]
    v = t.column("v").to_numpy() * config.factor
    return {"table": pa.table({"i": t.column("i"), "v": v}), "blob": v.tobytes()}


def _hold(stage: str) -> None:
    """Lets a test hold a stage until the file $TOY_GATE exists (at most 60 s), e.g. until a
    second process waits on its lock; $TOY_GATE_STAGES names the stages held (`double`)."""
    gate = os.environ.get("TOY_GATE")
    if not gate or stage not in os.environ.get("TOY_GATE_STAGES", "double").split(","):
        return
    deadline = time.monotonic() + 60
    while not Path(gate).exists() and time.monotonic() < deadline:
        time.sleep(0.02)


def _summary(config: SummaryConfig, inputs: dict[str, Any]) -> dict[str, Any]:
    _mark("summary")
    if config.fail:
        raise RuntimeError("deliberate failure")
    v = inputs["double.table"].column("v").to_numpy()
    return {"summary": {config.label: float(v.sum()), "n": len(v)}}


def _count(config: CountConfig, inputs: dict[str, Any]) -> dict[str, Any]:
    _mark("count")
    _hold("count")
    v = inputs["source.table"].column("v").to_numpy()
    hist, _ = np.histogram(v, bins=config.bins)
    return {"hist": pa.table({"count": hist.astype(np.int64)})}


SOURCE = Stage(
    "source", 1, SourceConfig, (DATASET,), (Output("table", "parquet", "t.parquet"),), _source
)
DOUBLE = Stage(
    "double",
    1,
    DoubleConfig,
    (Input("source", "table"),),
    (Output("table", "parquet", "d.parquet"), Output("blob", "bytes", "d.bin")),
    _double,
)
SUMMARY = Stage(
    "summary",
    1,
    SummaryConfig,
    (Input("double", "table"),),
    (Output("summary", "json", "s.json"),),
    _summary,
)
COUNT = Stage(
    "count",
    1,
    CountConfig,
    (Input("source", "table"),),
    (Output("hist", "parquet", "h.parquet"),),
    _count,
)
TOY_STAGES = (SOURCE, DOUBLE, SUMMARY, COUNT)


def _parts(path: Path) -> list[Path]:
    return [path]


def _open(path: Path, _section: Any) -> bytes:
    return path.read_bytes()


GRAPH = Graph(stages=TOY_STAGES, parts=_parts, open=_open)
"""The toy graph: passed to the engine directly, or named as $SONARMAP_GRAPH=toy_stages:GRAPH
for the CLI (and so its sweep workers)."""
