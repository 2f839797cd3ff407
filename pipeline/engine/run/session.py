"""Glue between the CLI and the engine: resolve a dataset, config and store into a context."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from sonarmap.pipeline.engine.config.load import load_config
from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.engine.hashing import (
    FingerprintCache,
    changed_file,
    changed_while_read,
    file_identities,
)
from sonarmap.pipeline.engine.run.graph import Graph
from sonarmap.pipeline.engine.run.planned import DatasetSpec
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
from sonarmap.pipeline.engine.store.disk import disk_error
from sonarmap.stages.base import Stage

__all__ = ["DEFAULT_STORE", "RunContext", "dataset_spec", "make_context", "open_context"]

DEFAULT_STORE = Path("data/store")


def dataset_spec(
    path: Path, store: ArtifactStore, graph: Graph, *, create_store: bool = True
) -> DatasetSpec:
    """Fingerprint a dataset as `graph` finds its files (cached by size/mtime/inode in
    the store, which `create_store=False` never creates: `status`, `view`); the spec
    carries the graph's opener and codecs."""
    if not path.exists():
        raise SourceError(f"{path}: no such file or directory")
    files = list(graph.parts(path))
    if not files:
        raise SourceError(f"{path}: no dataset files found")
    remember = create_store or store.root.is_dir()
    cache = FingerprintCache(store.root / ".cache" / "fingerprints.json", remember)
    root = path if path.is_dir() else path.parent
    identity = file_identities(files)
    try:
        fingerprint = cache.dataset_fingerprint(files, root)
    except OSError as err:  # the store's cache on a full, read-only or odd filesystem
        raise disk_error(err, store.root / ".cache") from err
    changed = changed_file(identity)  # written to while hashed: no content to name
    if changed is not None:
        raise changed_while_read(changed)
    return DatasetSpec(
        path=path, fingerprint=fingerprint, open=graph.open, codecs=graph.codecs,
        identity=identity,
    )  # fmt: skip


@dataclass(frozen=True)
class RunContext:
    stages: tuple[Stage, ...]
    config: BaseModel
    store: ArtifactStore
    dataset: DatasetSpec


def open_context(
    dataset: Path,
    graph: Graph,
    *,
    config_path: Path | None = None,
    overrides: Sequence[str] = (),
    store_dir: Path = DEFAULT_STORE,
    create_store: bool = True,
) -> RunContext:
    """`graph` on `dataset`: validate the config first (cheap), then fingerprint."""
    config = load_config(graph.config_stages, config_path, overrides, graph.extra_sections)
    pin = getattr(graph, "pin", None)  # a graph given by $SONARMAP_GRAPH may have none
    config = pin(config) if pin is not None else config
    store = ArtifactStore(store_dir)
    spec = dataset_spec(dataset, store, graph, create_store=create_store)
    return RunContext(graph.stages, config, store, spec)


def make_context(
    dataset: Path,
    *,
    stages: Sequence[Stage],
    config_stages: Sequence[Stage] | None = None,
    config_path: Path | None = None,
    overrides: Sequence[str] = (),
    extra_sections: Mapping[str, type[BaseModel]] | None = None,
    store_dir: Path = DEFAULT_STORE,
    graph: Graph | None = None,
    parts: Callable[[Path], list[Path]] | None = None,
    opener: Callable[[Any], Any] | None = None,
) -> RunContext:
    """A context for explicit stages (tests, benchmarks): `graph`'s way of finding and
    opening a dataset (and its codecs), where `parts` / `opener(section)` do not replace
    it; with no `graph`, both must be given."""
    found: Callable[[Path], Sequence[Path]]
    if graph is None:
        if parts is None or opener is None:
            raise TypeError("make_context needs a graph, or both parts and opener")
        found, opened, codecs = parts, _by_section(opener), {}
    else:
        found = parts or graph.parts
        opened = graph.open if opener is None else _by_section(opener)
        codecs = dict(graph.codecs)
    config = load_config(config_stages or stages, config_path, overrides, extra_sections)
    store = ArtifactStore(store_dir)
    graph = Graph(tuple(stages), found, opened, codecs=codecs)
    return RunContext(tuple(stages), config, store, dataset_spec(dataset, store, graph))


def _by_section(opener: Callable[[Any], Any]) -> Callable[[Path, Any], Any]:
    def open_dataset(_path: Path, section: Any) -> Any:
        return opener(section)

    return open_dataset
