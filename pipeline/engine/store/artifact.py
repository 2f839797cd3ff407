"""What a store holds: a committed artifact, and a directory that is not one.

Plain records (and the path check their files go through), below the store, its
integrity checks and its garbage collector, so all of them can use them."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sonarmap.pipeline.engine.errors import ArtifactCorrupt, StoreError

__all__ = ["PULL_CACHE", "ArtifactRef", "Problem", "escapes", "safe_relative"]


PULL_CACHE = ".cache/pull"
"""Files an interrupted `pull` verified, by sha256, so the next pull resumes; `gc` removes
them once stale."""


def escapes(relative: str) -> bool:
    """Whether a manifest's file name leaves its artifact by its text alone: empty,
    absolute, or climbing out with `..`."""
    candidate = Path(relative)
    return relative.strip() == "" or candidate.is_absolute() or ".." in candidate.parts


def safe_relative(root: Path, relative: str) -> Path:
    """`root / relative`, refusing absolute paths and anything that escapes `root`."""
    candidate = Path(relative)
    if escapes(relative):
        raise ArtifactCorrupt(f"path '{relative}' escapes the artifact directory {root}")
    resolved = (root / candidate).resolve()
    if not resolved.is_relative_to(root.resolve()):
        raise ArtifactCorrupt(f"path '{relative}' escapes the artifact directory {root}")
    return root / candidate


@dataclass(frozen=True)
class Problem:
    """A directory under a stage folder that is not a usable artifact, and why."""

    stage: str
    key: str
    path: Path
    reason: str

    def __str__(self) -> str:
        return f"{self.stage}/{self.key[:12]}: {self.reason}"


@dataclass(frozen=True)
class ArtifactRef:
    """A committed artifact: where it is and what its manifest says."""

    stage: str
    key: str
    path: Path
    manifest: dict[str, Any]

    def file(self, name: str) -> Path:
        """Path of one of its files (checked against the manifest)."""
        if name not in self.manifest.get("files", {}):
            raise StoreError(f"{self.stage}/{self.key[:12]} has no file '{name}'")
        return safe_relative(self.path, name)
