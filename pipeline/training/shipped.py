"""The default classifier shipped with the code, so a fresh clone neither simulates nor trains.

`configs/model/` is a read-only artifact store that holds the default model: the `train`
artifact of the default `training` section, with its manifest (sha256 of every file).
Beside it, `lock.json` names the recording that each training set's simulation
produces: its file name, its recipe (scene sha256, seed, goals, simulator version) and
its sha256, which is the recording's dataset fingerprint.

The `train` key covers the training recordings' fingerprints. With the lock, it can be
planned without them on disk: a training set whose recording is missing or stale takes
the lock's fingerprint when the lock has its exact recipe. This rests on the
simulator's rule that the same recipe gives the same bytes (`sim/version.py`), the
rule that already lets a recipe sidecar stand for a recording. When the planned key is
shipped, its files are checked against their sha256 and it enters the model cache
like a pulled model.

Anything that moves the model's key misses the shipped model, and the machine trains as
before: a scene, the simulator version, a keyframes/features/train version or setting.
`sonarmap train --ship` rewrites the shipped model from the one this machine resolves.
`tests/test_shipped_model.py` fails while the shipped model is stale, so a change that
retrains every new user's model says so in CI.
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from sonarmap.pipeline.engine.hashing import canonical_json
from sonarmap.pipeline.engine.store.artifact_store import (
    ArtifactRef,
    ArtifactStore,
    verify_artifact_dir,
)
from sonarmap.pipeline.package_data import package_root
from sonarmap.pipeline.training.datasets import Simulation

__all__ = [
    "LOCK_FILE",
    "PROJECT_ROOT",
    "lock_disagreements",
    "locked_fingerprints",
    "read_lock",
    "ship",
    "shipped_models",
    "shipped_root",
    "shipped_store",
]

PROJECT_ROOT = package_root()
LOCK_FILE = "lock.json"
LOCK_FORMAT = 1


def shipped_root(setting: str | None) -> Path | None:
    """The shipped-model folder of `training.shipped_models` (relative: to the project)."""
    if not setting:
        return None
    path = Path(setting)
    return path if path.is_absolute() else PROJECT_ROOT / path


def shipped_store(setting: str | None) -> ArtifactStore | None:
    """The shipped models as a (read-only) artifact store, or None when there are none."""
    root = shipped_root(setting)
    return ArtifactStore(root) if root is not None and (root / "train").is_dir() else None


def shipped_models(setting: str | None) -> list[tuple[str, str, str]]:
    """(stage, key, sha256 of model.pt) of every shipped model: the leaves and pins that
    `push` and `pull` use (`sonarmap.pipeline.engine.share.trust.TrustPolicy`)."""
    store = shipped_store(setting)
    if store is None:
        return []
    found = []
    for ref in store.iter_artifacts():
        entry = (ref.manifest.get("files") or {}).get("model.pt") or {}
        if entry.get("sha256"):
            found.append((ref.stage, ref.key, str(entry["sha256"])))
    return found


def _entry_key(file_name: str, recipe: Mapping[str, Any]) -> str:
    return f"{file_name}\n{canonical_json(dict(recipe)).decode()}"


def read_lock(root: Path) -> dict[str, str]:
    """{file name + canonical recipe: sha256} of `root/lock.json`; {} when absent or unreadable.

    An unreadable lock only costs a simulation, so it is not an error.
    """
    try:
        doc = json.loads((root / LOCK_FILE).read_text())
        if doc.get("format") != LOCK_FORMAT:
            return {}
        return {_entry_key(str(d["file"]), d["recipe"]): str(d["sha256"]) for d in doc["datasets"]}
    except (OSError, ValueError, KeyError, TypeError):
        return {}


def locked_fingerprints(sims: Sequence[Simulation], setting: str | None) -> dict[Path, str] | None:
    """Fingerprints for the simulations not on disk, from the lock.

    Returns:
        {recording path: sha256} for each simulation whose recording is missing or stale
        (an up-to-date recording is fingerprinted from its file as usual); None when one
        of those is not in the lock, so planning needs the simulation itself.
    """
    missing = [s for s in sims if not s.is_current()]
    if not missing:
        return {}
    root = shipped_root(setting)
    lock = read_lock(root) if root is not None else {}
    found: dict[Path, str] = {}
    for sim in missing:
        sha = lock.get(_entry_key(sim.out.name, sim.recipe()))
        if sha is None:
            return None
        found[sim.out] = sha
    return found


def lock_disagreements(
    sims: Sequence[Simulation], fingerprints: Mapping[Path, str], setting: str | None
) -> list[str]:
    """One line for each simulated recording whose bytes differ from those the lock names
    for the same recipe.

    The lock rests on the simulator's rule that a recipe gives the same bytes. That holds
    on one machine, but not across every library version and CPU: the ray caster and the
    noise round differently, and a pixel one rounding step away from the next grey level
    changes the file. Such a machine plans another `train` key, so it trains its own model
    (minutes), and that model is not the shipped one: the user is told why.
    """
    root = shipped_root(setting)
    lock = read_lock(root) if root is not None else {}
    lines = []
    for sim in sims:
        want = lock.get(_entry_key(sim.out.name, sim.recipe()))
        got = fingerprints.get(sim.out)
        if want is not None and got is not None and want != got:
            lines.append(
                f"{sim.out}: simulated here with other bytes than the shipped model's lock"
                f" names for the same recipe (sha256 {got[:12]}… against {want[:12]}…): this"
                " machine's libraries or CPU round the simulation differently, so the model"
                " trained from it is not the shipped one"
            )
    return lines


def ship(
    ref: ArtifactRef, sims: Sequence[Simulation], fingerprints: Sequence[str], root: Path
) -> Path:
    """Replace the shipped model in `root` by `ref` and the lock of its simulations.

    Args:
        ref: the verified `train` artifact of the default training section.
        sims: that section's simulations, whose recordings are on disk.
        fingerprints: their dataset fingerprints, in the same order.
        root: the shipped-model folder (`configs/model`).

    The new folder is built beside the old one and swapped in by rename, so a failure
    leaves the old one whole.
    """
    verify_artifact_dir(ref.path, ref.manifest)
    tmp = root.with_name(f".{root.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}")
    try:
        shutil.copytree(ref.path, tmp / ref.stage / ref.key)
        lock = {
            "format": LOCK_FORMAT,
            "train_key": ref.key,
            "datasets": [
                {"file": s.out.name, "recipe": s.recipe(), "sha256": fp}
                for s, fp in zip(sims, fingerprints, strict=True)
            ],
        }
        (tmp / LOCK_FILE).write_text(json.dumps(lock, indent=2, sort_keys=True) + "\n")
        old = root.with_name(f".{root.name}.old-{os.getpid()}")
        had_old = root.exists()
        if had_old:
            root.rename(old)
        try:
            tmp.rename(root)
        except OSError:
            if had_old:
                old.rename(root)  # the old shipped model stays whole
            raise
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return root
