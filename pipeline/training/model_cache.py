"""One default model for every store of a user: the model cache.

The default classifier is trained once into the model cache, an ordinary artifact store
at `<training.directory>/store`, by default in the user's cache directory
(`sonarmap.pipeline.training.cache_dir`), with atomic commits, per-key locks, manifests with sha256,
which also holds the training datasets' keyframes and features. A run's store gets a
verified copy of the `train` artifact it uses, so `show`, `push` and `pull` see the
model where they always did. The `train` key is planned without computing anything,
so a fresh store on a machine that has the model trains nothing and builds nothing:

1. the run's store has the model (e.g. pulled from a colleague): use it, and publish it
   to the cache when the cache lacks it;
2. the cache has it: check every file's sha256 against its manifest, copy it in;
3. the project ships it (`configs/model`, `sonarmap.pipeline.training.shipped`): verified into
   the cache, then copied in; planned from the shipped lock, so nothing is simulated;
4. none: simulate the training sets, train into the cache (once per machine), copy it in.
"""

from __future__ import annotations

import logging
import shutil
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel

from sonarmap.pipeline.engine.errors import ArtifactCorrupt
from sonarmap.pipeline.engine.store.artifact_store import (
    ArtifactRef,
    ArtifactStore,
    safe_relative,
    verify_artifact_dir,
)
from sonarmap.pipeline.engine.store.units import copy_units
from sonarmap.pipeline.training.cache_dir import default_training_directory
from sonarmap.stages.base import Stage

__all__ = [
    "DEFAULT_MODEL_CACHE",
    "ResolvedModel",
    "copy_verified",
    "describe",
    "located_default_model",
    "model_cache",
    "planned_default_model",
    "resolve_default_model",
    "resolve_model",
    "same_model",
]

log = logging.getLogger(__name__)

CACHE_DIR = "store"
"""The model cache's folder inside `training.directory`."""

DEFAULT_MODEL_CACHE = default_training_directory() / CACHE_DIR
"""The model cache of the default `training.directory`, in the user's cache directory or
under `$SONARMAP_CACHE_DIR` as set when sonarmap starts (where `push` looks; a test keeps
it equal to `TrainingDataConfig().directory`, which stays the one default)."""

Source = Literal["store", "model cache", "shipped", "trained", "given"]


@dataclass(frozen=True)
class ResolvedModel:
    """The model a run uses: the train stage, its artifact in the run's store, and where
    it came from ("store": already there, "model cache": copied, "trained": just now)."""

    stage: Stage
    ref: ArtifactRef
    source: Source
    cache: Path

    def to_json(self) -> dict[str, Any]:
        return {
            "stage": self.ref.stage,
            "key": self.ref.key,
            "source": self.source,
            "path": str(self.ref.path),
            "cache": str(self.cache),
        }

    def describe(self) -> str:
        """One line for the terminal: which model, from where."""
        return describe(self.to_json())


def describe(model: Mapping[str, Any]) -> str:
    """ "classifier: train/<key> (from where)" of a `ResolvedModel.to_json()` document."""
    where = {
        "store": "found in the store",
        "model cache": f"copied from the model cache {model.get('cache')}",
        "shipped": f"the shipped model, copied to the model cache {model.get('cache')}",
        "trained": f"trained into the model cache {model.get('cache')}",
        "given": "given by classify.model",
    }.get(str(model.get("source")), str(model.get("source")))
    return f"classifier: train/{str(model.get('key'))[:12]} ({where})"


def model_cache(config: BaseModel) -> ArtifactStore:
    """The machine-wide model cache of `config`'s `training` section."""
    from sonarmap.pipeline.training.config import TrainingDataConfig

    training: TrainingDataConfig = getattr(config, "training", TrainingDataConfig())
    return ArtifactStore(Path(training.directory) / CACHE_DIR)


def copy_verified(ref: ArtifactRef, dest: ArtifactStore) -> ArtifactRef:
    """Commit a copy of `ref` into `dest`, atomically, only if every copied file matches
    the source manifest's size and sha256 (and its key its recipe).

    Raises:
        ArtifactCorrupt: a file differs; nothing becomes visible in `dest`.
    """
    files: Mapping[str, Any] = ref.manifest.get("files") or {}

    def copy(tmp: Path) -> Mapping[str, Any]:
        # Errors name the folder copied from, not the store's temporary one.
        for rel in files:
            target = safe_relative(tmp, rel)
            target.parent.mkdir(parents=True, exist_ok=True)
            try:
                shutil.copyfile(safe_relative(ref.path, rel), target)
            except FileNotFoundError:
                raise ArtifactCorrupt(
                    f"{ref.path}: its manifest lists '{rel}', not there"
                ) from None
        try:
            verify_artifact_dir(tmp, ref.manifest)
        except ArtifactCorrupt as err:
            raise ArtifactCorrupt(str(err).replace(str(tmp), str(ref.path))) from None
        return {}

    # its work units first: the committed copy lists them (store.units)
    copy_units(ref.path.parent.parent, dest.root, ref.stage, ref.manifest)
    keep = {k: v for k, v in ref.manifest.items() if k not in ("files", "build_seconds")}
    return dest.commit(ref.stage, ref.key, copy, keep)


def _record_use(store: ArtifactStore, ref: ArtifactRef, source: Source) -> None:
    """A run record naming the model, so `gc` keeps the copy a run relies on."""
    record = {
        "dataset": f"model:{ref.key}",
        "updated_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "source": source,
        "stages": {"train": {"key": ref.key, "recipe": ref.manifest.get("recipe", {})}},
    }
    store.record_run(f"model-{ref.key[:20]}", record)


def same_model(held: ArtifactRef | None, claimed: ArtifactRef, where: str) -> None:
    """Refuse `claimed` when `held` is another model under the same key: a key is derived
    from a recipe, which a manifest can copy, so the model's bytes decide which it is (a
    folder claiming the shipped model's recipe took its place in the store)."""
    from sonarmap.pipeline.engine.share.trust import TrustPolicy

    if held is None:
        return
    mine, theirs = TrustPolicy.model_sha(claimed.manifest), TrustPolicy.model_sha(held.manifest)
    if mine != theirs:
        raise ArtifactCorrupt(
            f"{where}: names train/{claimed.key[:12]} (its recipe) but holds another model.pt"
            f" (sha256 {mine[:12]}, not {theirs[:12]}): a model is known by its bytes;"
            " retrain it (`sonarmap train -o DIR`) for a key of its own"
        )


def _substitute(shipped: ArtifactRef | None, held: ArtifactRef) -> bool:
    """Say when a store holds other weights under a shipped model's key: a substitute a
    user pinned and pulled is allowed (its classify keys are its own), but the run's
    `classifier:` line names the shipped key, so the bytes are named too. True for one."""
    from sonarmap.pipeline.engine.share.trust import TrustPolicy

    if shipped is None:
        return False
    theirs, mine = TrustPolicy.model_sha(shipped.manifest), TrustPolicy.model_sha(held.manifest)
    if theirs != mine:
        log.warning(
            "classifier: %s holds a model.pt other than the shipped model's (sha256 %s, not"
            " %s): a substitute pinned by you; its classes and classify keys are its own",
            held.path,
            mine[:12],
            theirs[:12],
        )
        return True
    return False


def _find_or_ship(
    key: str, store: ArtifactStore, cache: ArtifactStore, shipped: ArtifactStore | None
) -> tuple[ArtifactRef, Source] | None:
    """The model `key` from the run's store, the model cache or the shipped models (those
    two copied in, verified), or None when it must be trained. A copy of a shipped key
    with other bytes (a substitute the user pinned and pulled) is said (`_substitute`)."""
    bundled = shipped.get("train", key) if shipped is not None else None
    ref = store.get("train", key)
    if ref is not None:
        substitute = _substitute(bundled, ref)
        # A substitute stays in its store: in the model cache, under the shipped key, every
        # other store's default run would find it and refuse the shipped model.
        if (
            not substitute
            and cache.get("train", key) is None
            and cache.root.resolve() != store.root.resolve()
        ):
            copy_verified(ref, cache)
        return ref, "store"
    cached = cache.get("train", key)
    if cached is not None:
        _substitute(bundled, cached)
    source: Source = "model cache"
    if cached is None and bundled is not None:
        try:
            cached = copy_verified(bundled, cache)
        except ArtifactCorrupt as err:
            raise ArtifactCorrupt(f"shipped model: {err} (restore {bundled.path})") from err
        source = "shipped"
    if cached is None:
        return None
    try:
        return copy_verified(cached, store), source
    except ArtifactCorrupt as err:
        raise ArtifactCorrupt(f"model cache: {err} (remove {cached.path} to retrain)") from err


def _planned_from_lock(config: BaseModel, cache: ArtifactStore) -> tuple[str, list[Path]] | None:
    """The default model's key and datasets, planned without simulating: recordings on
    disk are fingerprinted, the others taken from the shipped lock; None when the lock
    lacks one of them (planning then needs the simulation)."""
    from sonarmap.pipeline.training.config import TrainingDataConfig
    from sonarmap.pipeline.training.model import (
        ordered_datasets,
        plan_training,
        training_simulations,
    )
    from sonarmap.pipeline.training.shipped import locked_fingerprints

    training: TrainingDataConfig = getattr(config, "training", TrainingDataConfig())
    sims = training_simulations(training)
    locked = locked_fingerprints(sims, training.shipped_models)
    if locked is None:
        return None
    paths, heldout = ordered_datasets([s.out for s in sims], training)
    return plan_training(paths, config, cache, fingerprints=locked, heldout=heldout), paths


def located_default_model(
    store: ArtifactStore, config: BaseModel
) -> tuple[str, ArtifactRef | None]:
    """The default model's key and where it is at hand (the store, the model cache or the
    shipped models; None when nowhere), found without simulating, training or copying."""
    from sonarmap.pipeline.training.config import TrainingDataConfig
    from sonarmap.pipeline.training.shipped import shipped_store

    cache = model_cache(config)
    planned = _planned_from_lock(config, cache)
    if planned is None:
        return "", None
    training: TrainingDataConfig = getattr(config, "training", TrainingDataConfig())
    places = (store, cache, shipped_store(training.shipped_models))
    found = (s.get("train", planned[0]) for s in places if s is not None)
    return planned[0], next((ref for ref in found if ref is not None), None)


def planned_default_model(store: ArtifactStore, config: BaseModel) -> tuple[str, bool]:
    """The default model's key and whether it is at hand (store, cache or shipped), without
    simulating or training: for the demo, which simulates only what it will need."""
    key, ref = located_default_model(store, config)
    return key, ref is not None


def resolve_default_model(store: ArtifactStore, config: BaseModel) -> ResolvedModel:
    """The default model for `classify` in `store`: reused, copied from the cache or the
    shipped models, or trained.

    The key is planned first from the recordings on disk and, for those not simulated
    yet, the shipped model's lock (`sonarmap.pipeline.training.shipped`), so a machine with the
    model simulates nothing. Only a miss simulates the training sets, plans again from
    the real files, and trains.

    Raises:
        ArtifactCorrupt: the cached or shipped model's files do not match its manifest
            (the message names the artifact directory to remove or restore).
        SourceError: a training dataset is unusable.
    """
    from sonarmap.pipeline.training.annotations import annotation_path
    from sonarmap.pipeline.training.config import TrainingDataConfig
    from sonarmap.pipeline.training.model import (
        dataset_fingerprints,
        plan_training,
        train_on,
        training_datasets,
        training_simulations,
        training_stage_for,
    )
    from sonarmap.pipeline.training.shipped import lock_disagreements, shipped_store
    from sonarmap.pipeline.training.worlds import heldout_count

    training: TrainingDataConfig = getattr(config, "training", TrainingDataConfig())
    cache = model_cache(config)
    shipped = shipped_store(training.shipped_models)
    found = None
    planned = _planned_from_lock(config, cache)
    if planned is not None:
        key, paths = planned
        found = _find_or_ship(key, store, cache, shipped)
    if found is None:
        paths = training_datasets(training)
        key = plan_training(paths, config, cache, heldout=heldout_count(training))
        found = _find_or_ship(key, store, cache, shipped)
    source: Source
    if found is None:
        sims = training_simulations(training)
        on_disk = dataset_fingerprints([s.out for s in sims], cache)
        for line in lock_disagreements(sims, on_disk, training.shipped_models):
            log.warning("%s", line)
        trained = train_on(paths, config, cache, heldout=heldout_count(training))
        ref, source = copy_verified(trained, store), "trained"
    else:
        ref, source = found
    annotated = [i for i, p in enumerate(paths) if annotation_path(p) is not None]
    stage = training_stage_for(len(paths), annotated, heldout=heldout_count(training))
    _record_use(store, ref, source)
    chosen = ResolvedModel(stage, ref, source, cache.root)
    log.info("%s", chosen.describe())
    return chosen


def resolve_model(store: ArtifactStore, config: BaseModel) -> tuple[Stage, ArtifactRef]:
    """The default model's training stage and artifact in `store` (`resolve_default_model`)."""
    chosen = resolve_default_model(store, config)
    return chosen.stage, chosen.ref
