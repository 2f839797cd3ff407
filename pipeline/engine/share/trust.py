"""What `pull` believes of a remote: recipes are re-hashed, models must be pinned.

A remote's manifest can only prove that its files are the ones its author listed. For
data stages that is enough once the key is re-derived from the recipe: the recipe names
the stage, the config and the input keys, and a wrong file under an honest recipe is
at worst a wrong intermediate that the user asked for by key. A model is different: a
model with swapped weights or labels changes every map made with it and nothing
downstream can notice. So a model is accepted only when its files' sha256s are pinned:
the shipped model's (`configs/model`), ones the user lists (`--trust-model`,
`SONARMAP_TRUSTED_MODELS`), or one this machine trained (it is then already local and
never pulled).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sonarmap.pipeline.engine.errors import ArtifactCorrupt, StoreError

__all__ = [
    "MODEL_FILE",
    "MODEL_STAGES",
    "RESERVED",
    "TrustPolicy",
    "check_model_file",
    "check_not_reserved",
    "env_pins",
]

MODEL_STAGES = frozenset({"train"})
"""Stages whose artifacts are models: accepted from a remote only when pinned."""
MODEL_FILE = "model.pt"
RESERVED = frozenset({"runs", "units"})
"""Store folders that are not stages (and every name starting with `.` or `_`)."""
_SHA = re.compile(r"^[0-9a-f]{64}$")


def check_not_reserved(stage: str, where: str) -> None:
    """Refuse a stage name that is one of the store's own folders."""
    if stage in RESERVED or stage.startswith((".", "_")) or not stage.isidentifier():
        raise ArtifactCorrupt(f"{where}: '{stage[:40]}' is a reserved store folder, not a stage")


def env_pins() -> frozenset[str]:
    """sha256s listed in `SONARMAP_TRUSTED_MODELS` (comma or space separated)."""
    return frozenset(
        s for s in re.split(r"[,\s]+", os.environ.get("SONARMAP_TRUSTED_MODELS", "")) if s
    )


@dataclass(frozen=True)
class TrustPolicy:
    """Pinned model sha256s, and the artifacts that are leaves (shipped models)."""

    pinned: frozenset[str] = frozenset()
    leaves: frozenset[tuple[str, str]] = field(default_factory=frozenset)
    required: Mapping[str, frozenset[str]] = field(default_factory=dict)
    """Stage -> the files every artifact of it holds (its outputs that are not optional):
    a manifest listing none would be committed, verified and then fail downstream."""

    def check_files(self, stage: str, files: Iterable[str], where: str) -> None:
        """Refuse a manifest that lacks a file every artifact of `stage` has."""
        from sonarmap.pipeline.engine.store.integrity import check_required_files

        check_required_files(stage, files, self.required, where)

    @classmethod
    def build(
        cls,
        pins: Iterable[str] = (),
        leaves: Iterable[tuple[str, str, str]] = (),
        required: Mapping[str, frozenset[str]] | None = None,
    ) -> TrustPolicy:
        """From user pins, (stage, key, model sha256) of each shipped model and each
        stage's required files.

        Raises:
            StoreError: a pin that is not a 64-digit lowercase sha256.
        """
        pins = [p.strip().lower() for p in pins]
        for pin in pins:
            if not _SHA.match(pin):
                raise StoreError(
                    f"--trust-model (or SONARMAP_TRUSTED_MODELS): '{pin[:70]}' is not a sha256"
                    " (64 hex digits)"
                )
        leaf_list = list(leaves)
        return cls(
            frozenset(pins) | {sha for _, _, sha in leaf_list},
            frozenset((stage, key) for stage, key, _ in leaf_list),
            dict(required or {}),
        )

    def is_leaf(self, stage: str, key: str, manifest: Mapping[str, Any]) -> bool:
        """A shipped model: its provenance is the lock, not artifacts to fetch."""
        return (stage, key) in self.leaves and self.model_sha(manifest) in self.pinned

    @staticmethod
    def model_sha(manifest: Mapping[str, Any]) -> str:
        entry = (manifest.get("files") or {}).get(MODEL_FILE) or {}
        return str(entry.get("sha256", ""))

    def check_model(self, stage: str, key: str, manifest: Mapping[str, Any], where: str) -> None:
        """Refuse a model artifact whose model file's sha256 is not pinned."""
        if stage not in MODEL_STAGES:
            return
        sha = self.model_sha(manifest)
        if not sha:
            raise ArtifactCorrupt(f"{where}: a {stage} artifact without '{MODEL_FILE}'")
        if sha not in self.pinned:
            raise ArtifactCorrupt(
                f"{where}: model '{MODEL_FILE}' (sha256 {sha}) is not pinned; if you trust "
                f"its author, pull again with --trust-model {sha}, or train it here"
            )


def check_model_file(path: Path, where: str) -> None:
    """Load a model file the way `classify` will (`model_from_bytes`: `weights_only=True`,
    so no pickle code runs) and refuse it when that fails."""
    from sonarmap.stages.classify.cnn import model_from_bytes

    try:
        model_from_bytes(path.read_bytes())
    except ValueError as err:
        raise ArtifactCorrupt(f"{where}: '{path.name}' is {err}") from err
