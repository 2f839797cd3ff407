"""What a run is about and what the planner decided: plain records, no behaviour.

They sit apart from the planner and runner so run records, progress and the session
can name them without importing either.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sonarmap.pipeline.engine.hashing import Identity
from sonarmap.stages.base import Stage

if TYPE_CHECKING:
    from sonarmap.pipeline.engine.store.codecs import Codec

__all__ = ["DatasetSpec", "PlannedStage"]


@dataclass(frozen=True)
class DatasetSpec:
    """The raw dataset a run reads: its path, content fingerprint, and the graph's opener
    and codecs.

    `open(path, section)` (the graph's `open`) returns what the first stage's `DATASET`
    input binds to (a `Recording` for real runs); the runner calls it only when that
    stage must run, once per run and config section. `codecs` (the graph's) store the
    outputs of kinds beyond parquet, json and bytes; they travel with the dataset to
    every computing process, as the opener does.
    """

    path: Path
    fingerprint: str
    open: Callable[[Path, Any], Any]
    codecs: Mapping[str, Codec] = field(default_factory=dict)
    identity: Identity = ()
    """Each file's stat identity when fingerprinted: a stage reading the dataset checks
    it did not change since (`sonarmap.pipeline.engine.hashing.changed_file`)."""


@dataclass(frozen=True)
class PlannedStage:
    """One stage of a plan: its key, the recipe hashed into it, hit or miss and why."""

    stage: Stage
    key: str
    recipe: dict[str, Any]
    hit: bool
    reason: str
