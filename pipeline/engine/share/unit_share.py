"""An artifact's per-keyframe work units on a remote: `<remote>/units/<stage>/<kk>/<key>`,
as in a store (`sonarmap.pipeline.engine.store.units`), listed with their sha256 and size
by the artifact's manifest. `push` sends them before the manifest; `pull` streams them
with the listed size as a hard limit and the sha256 checked, decodes each, and puts them
in the store's pulled pool (never among the units computed there) before committing the
artifacts that list them."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from sonarmap.pipeline.engine.store.artifact import ArtifactRef, safe_relative
from sonarmap.pipeline.engine.store.units import (
    held_unit_path,
    install_pulled_unit,
    unit_entries,
    unit_path,
)

__all__ = ["install_units", "staged_units", "unit_files"]


def unit_files(ref: ArtifactRef) -> Iterator[tuple[Path, str, dict[str, Any]]]:
    """(local path, path relative to the store root, manifest entry) of each listed unit."""
    held = ref.path.parent.parent  # the store holding the artifact (or a fallback)
    for key, entry in unit_entries(ref.manifest, f"{ref.stage}/{ref.key[:12]}").items():
        src = held_unit_path(held, ref.stage, key, entry)
        yield src, unit_path(Path("."), ref.stage, key).as_posix(), entry


def staged_units(
    staging: Path, stage: str, listed: Mapping[str, dict[str, Any]]
) -> Iterator[tuple[str, Path, dict[str, Any]]]:
    """(relative path, staging path, entry) of each unit to fetch (not one already fetched
    for another artifact listing it)."""
    for key, entry in listed.items():
        rel = unit_path(Path("."), stage, key).as_posix()
        dst = safe_relative(staging, rel)
        if dst.exists():
            continue
        dst.parent.mkdir(parents=True, exist_ok=True)
        yield rel, dst, entry


def install_units(
    root: Path, staging: Path, units: Mapping[tuple[str, str], Mapping[str, Any]]
) -> None:
    """Check each fetched unit is what its artifact lists and decodes, and put it in the
    pulled pool of the store at `root`."""
    for (stage, _), listed in units.items():
        for key, entry in listed.items():
            rel = unit_path(Path("."), stage, key).as_posix()
            data = safe_relative(staging, rel).read_bytes()
            install_pulled_unit(root, stage, key, entry, data, f"remote {rel}")
