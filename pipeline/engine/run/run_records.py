"""Run records: which artifacts a run used, rewritten as each stage commits.

`gc` keeps what any record names (and what is upstream of it); the planner reads the
previous record of a dataset to explain why a stage misses.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel

from sonarmap.pipeline.engine.config.load import READ_SECTIONS_KEY
from sonarmap.pipeline.engine.hashing import canonical_json
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
from sonarmap.stages.base import Input

if TYPE_CHECKING:
    from sonarmap.pipeline.engine.run.planned import DatasetSpec, PlannedStage

__all__ = ["miss_reason", "previous_recipes", "record_run", "run_id"]


def run_id(dataset: Path, config: BaseModel, stages: Sequence[str] = ()) -> str:
    """Identity of a run record: the dataset path, the whole effective config and the
    stages run (and bound from outside), so a run over another part of the graph on
    the same dataset (training's `train` after that dataset's `keyframes`) gets its
    own record instead of overwriting it."""
    digest = hashlib.sha256(
        canonical_json(
            {
                "dataset": str(dataset.resolve()),
                "config": config.model_dump(mode="json"),
                "stages": sorted(stages),
            }
        )
    )
    return digest.hexdigest()[:20]


def previous_recipes(store: ArtifactStore, dataset: Path) -> dict[str, dict[str, Any]]:
    """Per stage, its recipe in the most recent run on the same dataset path (to explain misses)."""
    target = str(dataset.resolve())
    recipes: dict[str, dict[str, Any]] = {}
    for record in reversed(store.run_records()):
        stages = record.get("stages")
        if record.get("dataset") != target or not isinstance(stages, Mapping):
            continue
        for name, info in stages.items():
            if isinstance(info, Mapping) and isinstance(info.get("recipe"), Mapping):
                recipes.setdefault(name, dict(info["recipe"]))
    return recipes


def record_run(
    store: ArtifactStore,
    dataset: DatasetSpec,
    config: BaseModel,
    planned: Sequence[PlannedStage],
    external: Mapping[str, Any],
    *,
    done: Mapping[str, PlannedStage] | None = None,
) -> None:
    """Write the run's record: every planned stage, or (`done`) those finished so far
    over what the previous record of the same run named (a failed rerun keeps its
    earlier complete run's later stages referenced)."""
    names = [p.stage.name for p in planned] + [f"external:{n}" for n in external]
    identity = run_id(dataset.path, config, names)
    stages: dict[str, Any] = {}
    if done is not None:
        previous = store.run_record(identity)
        old = previous.get("stages") if previous else None
        stages.update(old if isinstance(old, Mapping) else {})
    chosen = planned if done is None else list(done.values())
    stages.update({p.stage.name: {"key": p.key, "recipe": p.recipe} for p in chosen})
    record = {
        "dataset": str(dataset.path.resolve()),
        "fingerprint": dataset.fingerprint,
        "updated_at": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime())
        + f".{time.time_ns() % 10**9:09d}Z",
        "complete": done is None,
        "stages": stages,
    }
    store.record_run(identity, record)


def _config_diff(stage: str, old: Mapping[str, Any], new: Mapping[str, Any]) -> list[str]:
    """The settings that differ, each as `section.key old -> new`, nested sections gone
    into (the sections a stage reads of another's, `@reads`, under their own names)."""
    changes = []
    for k in sorted(set(old) | set(new), key=str):
        a, b = old.get(k), new.get(k)
        if a == b:
            continue
        path = "" if k == READ_SECTIONS_KEY else f"{stage}.{k}" if stage else str(k)
        if isinstance(a, Mapping) and isinstance(b, Mapping):
            changes += _config_diff(path, a, b)
        else:
            changes.append(f"{path} {_short(a)} -> {_short(b)}")
    return changes


def _short(value: Any, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def miss_reason(
    name: str, recipe: Mapping[str, Any], previous: Mapping[str, Any] | None, changed: set[str]
) -> str:
    """Why a stage misses the cache, from the recipe its last run recorded."""
    if not previous:
        return "not computed yet"
    if previous.get("version") != recipe["version"]:
        return f"version {previous.get('version')} -> {recipe['version']}"
    diff = _config_diff(name, previous.get("config", {}), recipe["config"])
    if diff:
        return "config changed: " + ", ".join(diff)
    if previous.get("dataset") != recipe.get("dataset"):
        return "dataset content changed"
    producers = {name: Input.parse(name).stage for name in recipe["inputs"]}
    used = previous.get("inputs") or {}
    if used != recipe["inputs"]:
        # The producers whose artifact differs from the one the last run used (an upstream
        # recomputed by an earlier run is a hit now, so `changed` alone may not name it).
        differ = {producers[k] for k, key in recipe["inputs"].items() if used.get(k) != key}
        names = sorted(differ & changed) or sorted(differ) or sorted(set(producers.values()))
        return "upstream " + ", ".join(names) + " recomputed"
    return "artifact missing (removed or never committed)"
