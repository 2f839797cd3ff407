"""A run pointed at a trained model: `--set classify.model=PATH` or `train/<key>`.

PATH is a train artifact's folder: one in any store (`<store>/train/<key>`) or the folder
`sonarmap train -o DIR` writes, which holds the artifact's manifest beside its files. The
files are checked against the manifest's sha256s before the model is copied into the
run's store, exactly as a pulled or shipped model is, so the run's classify key follows
the model's bytes, whichever way it was named (`sonarmap.pipeline.api.MODEL_INPUTS`).

A model trained without a validation split (`metrics.json` "n" = 0) says nothing of how
well it classifies: it is refused unless `classify.allow_unvalidated_model` is set.
"""

from __future__ import annotations

import json
from pathlib import Path

from pydantic import BaseModel

from sonarmap.pipeline.engine.errors import ArtifactCorrupt, SourceError
from sonarmap.pipeline.engine.store.artifact import ArtifactRef
from sonarmap.pipeline.engine.store.artifact_store import MANIFEST, ArtifactStore
from sonarmap.pipeline.engine.store.manifest import read_manifest
from sonarmap.pipeline.training.model_cache import (
    ResolvedModel,
    _record_use,
    copy_verified,
    model_cache,
    same_model,
)

__all__ = ["locate_given_model", "resolve_given_model"]


def _from_folder(folder: Path) -> ArtifactRef:
    manifest_path = folder / MANIFEST
    if not manifest_path.is_file():
        raise SourceError(
            f"classify.model: {folder}: no {MANIFEST} (give a train artifact's folder, the"
            " folder `sonarmap train -o DIR` writes, or train/<key>)"
        )
    try:
        _, manifest = read_manifest(manifest_path)
    except ArtifactCorrupt as err:
        raise SourceError(f"classify.model: {manifest_path}: {err}") from None
    if manifest.get("stage") != "train":
        raise SourceError(
            f"classify.model: {folder} holds a {manifest.get('stage')!r:.20} artifact,"
            " not a trained model"
        )
    return ArtifactRef("train", str(manifest.get("key")), folder, manifest)


def _from_key(prefix: str, stores: list[ArtifactStore]) -> ArtifactRef:
    for store in stores:
        found = [
            r
            for r in store.scan()
            if isinstance(r, ArtifactRef) and r.stage == "train" and r.key.startswith(prefix)
        ]
        if len(found) > 1:
            raise SourceError(f"classify.model: train/{prefix} is ambiguous in {store.root}")
        if found:
            return found[0]
    where = " or ".join(str(s.root) for s in stores)
    raise SourceError(f"classify.model: no trained model train/{prefix} in {where}")


def _check_validated(ref: ArtifactRef, allow_unvalidated: bool) -> None:
    try:
        metrics = json.loads(ref.file("metrics.json").read_text())
    except (OSError, ValueError) as err:
        raise SourceError(f"classify.model: {ref.path}: unreadable metrics.json ({err})") from None
    if not allow_unvalidated and not metrics.get("n"):
        raise SourceError(
            f"classify.model: {ref.path}: trained without a validation split (n=0);"
            " set classify.allow_unvalidated_model=true to use it anyway"
        )


def locate_given_model(
    spec: str, store: ArtifactStore, config: BaseModel, allow_unvalidated: bool
) -> ArtifactRef:
    """The model `spec` names, checked (there, a validated train artifact, no other model
    under its key) but not copied: what `status` plans with and `run` copies in.

    Raises:
        SourceError: nothing there, not a train artifact, or unvalidated (one line).
        ArtifactCorrupt: another model already holds its key.
    """
    from sonarmap.pipeline.training.shipped import shipped_store

    cache = model_cache(config)
    if spec.startswith("train/"):
        ref = _from_key(spec.removeprefix("train/"), [store, cache])
    else:
        ref = _from_folder(Path(spec).expanduser())
    _check_validated(ref, allow_unvalidated)
    shipped = shipped_store(getattr(getattr(config, "training", None), "shipped_models", None))
    where = f"classify.model: {spec}"
    for held in (shipped, store, cache):  # never under a key another model holds
        if held is not None and held.root.resolve() != ref.path.parent.parent.resolve():
            same_model(held.get("train", ref.key), ref, where)
    return ref


def resolve_given_model(
    spec: str, store: ArtifactStore, config: BaseModel, allow_unvalidated: bool
) -> ResolvedModel:
    """The model `spec` names, verified and copied into `store`.

    Raises:
        SourceError: nothing there, not a train artifact, or unvalidated (one line).
        ArtifactCorrupt: its files do not match its manifest, or another model holds its key.
    """
    from sonarmap.pipeline.training.model import training_stage_for

    ref = locate_given_model(spec, store, config, allow_unvalidated)
    local = store.get("train", ref.key)
    if local is None or local.path.resolve() != ref.path.resolve():
        try:
            local = copy_verified(ref, store)
        except ArtifactCorrupt as err:
            raise ArtifactCorrupt(f"classify.model: {err}") from err
    _record_use(store, local, "given")
    return ResolvedModel(training_stage_for(1, []), local, "given", model_cache(config).root)
