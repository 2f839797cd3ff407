"""The stage contract: what the engine needs to know about a stage, nothing more.

A stage is a pure function `run(config, inputs) -> outputs` over in-memory values
(Arrow tables, dicts, bytes, sequences of `KeyframeImages`), plus the metadata the
engine hashes into the artifact key. Stages never see paths, never print, never
import the engine.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict

__all__ = ["Output", "OutputKind", "Stage", "StageConfig"]

OutputKind = Literal["parquet", "json", "bytes", "frames"]
"""How the engine stores an output.

- parquet: a `pyarrow.Table`, written sorted as given, no timestamps in metadata.
- json: a JSON-serialisable dict (canonical, sorted keys).
- bytes: opaque bytes written verbatim (PNG, PLY, TUM text, torch state dict, ...).
- frames: an iterable of `schemas.sonar.KeyframeImages`, stored as ROS 2 MCAP and
  read back lazily as a sequence.
"""


class StageConfig(BaseModel):
    """Base of every stage config: frozen, unknown keys refused. Units in field names."""

    model_config = ConfigDict(frozen=True, extra="forbid")


@dataclass(frozen=True)
class Output:
    """One named output of a stage and the file it is stored in.

    `optional` outputs may be returned as None (e.g. a ground-truth mesh that a
    field dataset does not carry); the engine then writes no file and later binds None.
    """

    name: str
    kind: OutputKind
    filename: str
    optional: bool = False
    schema: Any = None
    """For parquet outputs: the `pyarrow.Schema` from `schemas/` the table must match
    (the engine validates column names and types before committing)."""


@dataclass(frozen=True)
class Stage:
    """A pipeline stage.

    Attributes:
        name: stage name, also the config section and the store folder.
        version: bumped by hand whenever the output could change (helpers included).
        config: the frozen pydantic model of this stage's config section.
        inputs: names the engine binds: "dataset" (the raw recording, first stage only)
            or "<stage>.<output>" of an upstream stage.
        outputs: what `run` returns, by name.
        run: `run(config, inputs) -> {output name: value}`.
    """

    name: str
    version: int
    config: type[StageConfig]
    inputs: tuple[str, ...]
    outputs: tuple[Output, ...]
    run: Callable[[Any, Mapping[str, Any]], Mapping[str, Any]]
    description: str = ""

    @property
    def upstream(self) -> tuple[str, ...]:
        """Names of the upstream stages this stage reads from (in input order, unique)."""
        seen: list[str] = []
        for item in self.inputs:
            if item == "dataset":
                continue
            stage = item.split(".", 1)[0]
            if stage not in seen:
                seen.append(stage)
        return tuple(seen)
