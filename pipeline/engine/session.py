"""Glue between the CLI and the engine: resolve a dataset, config and store into a plan."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from pipeline.engine.config import load_config
from pipeline.engine.disk import disk_error
from pipeline.engine.errors import SourceError
from pipeline.engine.hashing import FingerprintCache
from pipeline.engine.runner import DatasetSpec
from pipeline.engine.store import ArtifactStore
from stages.base import Stage

__all__ = ["DEFAULT_STORE", "RunContext", "dataset_spec", "make_context"]

DEFAULT_STORE = Path("data/store")


def _default_parts(path: Path) -> list[Path]:
    from pipeline.engine.registry import alternative_graph

    alt = alternative_graph()
    if alt is not None:
        return list(alt.parts(path))
    from pipeline.readers import dataset_fingerprint_parts

    return list(dataset_fingerprint_parts(path))


def _default_open(path: Path) -> Callable[[Any], Any]:
    """The dataset's opener. A recording is opened once per reader config and run: the
    stages reading it (keyframes, submaps) share what it has read (its navigation,
    which on interleaved recordings costs a pass decompressing every chunk)."""
    opened: dict[str, Any] = {}

    def opener(section: Any) -> Any:
        from pipeline.engine.registry import alternative_graph

        alt = alternative_graph()
        if alt is not None:
            return alt.open(path, section)
        from pipeline.readers import open_recording

        key = section.model_dump_json() if isinstance(section, BaseModel) else repr(section)
        if key not in opened:
            opened[key] = open_recording(path, section)
        return opened[key]

    return opener


def dataset_spec(
    path: Path,
    store: ArtifactStore,
    *,
    parts: Callable[[Path], list[Path]] | None = None,
    opener: Callable[[Any], Any] | None = None,
) -> DatasetSpec:
    """Fingerprint a dataset (cached by size/mtime/inode) and prepare its opener."""
    if not path.exists():
        raise SourceError(f"{path}: no such file or directory")
    files = (parts or _default_parts)(path)
    if not files:
        raise SourceError(f"{path}: no dataset files found")
    cache = FingerprintCache(store.root / ".cache" / "fingerprints.json")
    root = path if path.is_dir() else path.parent
    try:
        fingerprint = cache.dataset_fingerprint(files, root)
    except OSError as err:  # the store's cache on a full, read-only or odd filesystem
        raise disk_error(err, store.root / ".cache") from err
    return DatasetSpec(path=path, fingerprint=fingerprint, open=opener or _default_open(path))


@dataclass(frozen=True)
class RunContext:
    stages: tuple[Stage, ...]
    config: BaseModel
    store: ArtifactStore
    dataset: DatasetSpec


def make_context(
    dataset: Path,
    *,
    stages: Sequence[Stage],
    config_stages: Sequence[Stage] | None = None,
    config_path: Path | None = None,
    overrides: Sequence[str] = (),
    extra_sections: Mapping[str, type[BaseModel]] | None = None,
    store_dir: Path = DEFAULT_STORE,
    parts: Callable[[Path], list[Path]] | None = None,
    opener: Callable[[Any], Any] | None = None,
) -> RunContext:
    """Validate config first (cheap), then fingerprint the dataset."""
    config = load_config(config_stages or stages, config_path, overrides, extra_sections)
    store = ArtifactStore(store_dir)
    spec = dataset_spec(dataset, store, parts=parts, opener=opener)
    return RunContext(tuple(stages), config, store, spec)
