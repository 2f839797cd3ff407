"""What a store holds: a committed artifact, and a directory that is not one.

Plain records, below the store and its garbage collector, so both can use them."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline.engine.errors import StoreError
from pipeline.engine.integrity import safe_relative

__all__ = ["PULL_CACHE", "ArtifactRef", "Problem"]


PULL_CACHE = ".cache/pull"
"""Files an interrupted `pull` verified, by sha256, so the next pull resumes; `gc` removes
them once stale."""


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
