"""The stage graph a run executes (`Graph`), and `load_graph`: one named by
`$SONARMAP_GRAPH`, or the default the caller passes in.

The engine wires no graph of its own: the real pipeline's is built above it
(`sonarmap.pipeline.graph.default_graph`). The CLI builds the graph once (`load_graph`
of `$SONARMAP_GRAPH`, read there and nowhere else) and passes it to the session,
planner, sweep workers and commands.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.engine.store.codecs import Codec
from sonarmap.stages.base import Stage

__all__ = ["GRAPH_ENV", "Graph", "load_graph"]

GRAPH_ENV = "SONARMAP_GRAPH"
"""`module:attribute` of an alternative graph (a `Graph`, or any object with `.stages`,
`.parts(path)` and `.open(path, section)`): lets tests and experiments run other stage
graphs through the same engine. Read by the CLI only."""


@dataclass(frozen=True)
class Graph:
    """The stages a run executes and how it finds and opens its dataset.

    Attributes:
        stages: the mapping stages, in order (the first reads `DATASET`).
        parts: path -> the files whose contents fingerprint the dataset.
        open: (path, the reading stage's config section) -> the object bound to its
            `DATASET` input (a `sonarmap.schemas.recording.Recording` for the real pipeline).
        training: the classifier-training stage (None: the graph trains nothing).
        extra_sections: config sections of the engine that are not stages.
        spec: the `module:attribute` it was loaded from (None: the default graph).
        codecs: output kind -> its `Codec`, for the kinds beyond the engine's own
            (parquet, json, bytes): the real pipeline's `frames`.
        pin: config -> the config with the contents of the files it names pinned
            (`sonarmap.pipeline.readers.referenced_files`; None: it names none).
    """

    stages: tuple[Stage, ...]
    parts: Callable[[Path], Sequence[Path]]
    open: Callable[[Path, Any], Any]
    training: Stage | None = None
    extra_sections: Mapping[str, type[BaseModel]] = field(default_factory=dict)
    spec: str | None = None
    codecs: Mapping[str, Codec] = field(default_factory=dict)
    pin: Callable[[BaseModel], BaseModel] | None = None

    @property
    def config_stages(self) -> tuple[Stage, ...]:
        """Every stage with a config section: the mapping stages, then training."""
        return self.stages if self.training is None else (*self.stages, self.training)

    def stage(self, name: str) -> Stage:
        for stage in self.config_stages:
            if stage.name == name:
                return stage
        raise KeyError(name)


def load_graph(spec: str | None, default: Callable[[], Graph]) -> Graph:
    """The graph named by `spec` (`module:attribute`), or `default()` (None, "")."""
    if not spec:
        return default()
    module, _, attr = spec.partition(":")
    try:
        found = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError, ValueError) as err:
        raise ConfigError(f"${GRAPH_ENV}={spec[:200]}: cannot load ({err})") from err
    if isinstance(found, Graph):
        return found if found.spec == spec else Graph(**{**found.__dict__, "spec": spec})
    try:
        stages = tuple(found.stages)
        graph = Graph(
            stages=stages,
            parts=found.parts,
            open=found.open,
            spec=spec,
            codecs=dict(getattr(found, "codecs", {})),
        )
    except (AttributeError, TypeError) as err:
        raise ConfigError(f"${GRAPH_ENV}={spec[:200]}: not a stage graph ({err})") from err
    if not stages or not all(isinstance(s, Stage) for s in stages):
        raise ConfigError(f"${GRAPH_ENV}={spec[:200]}: not a stage graph (no stages)")
    return graph
