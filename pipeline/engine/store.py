"""The artifact store: `<store>/<stage>/<key>/` with `manifest.json` written last.

An artifact exists when, and only when, its directory holds a readable manifest.
Commits are atomic: files are built in a temporary directory inside the store,
fsynced, the manifest is written last, and the directory is renamed into place.
A per-key file lock makes a second process wait and then reuse the artifact.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import time
import uuid
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from filelock import FileLock

from pipeline.engine.errors import ArtifactCorrupt, StoreError
from pipeline.engine.hashing import STORE_FORMAT_VERSION, recipe_key, sha256_file

__all__ = ["MANIFEST", "ArtifactRef", "ArtifactStore", "safe_relative"]

log = logging.getLogger(__name__)
MANIFEST = "manifest.json"
_TMP = ".tmp"
_LOCKS = ".locks"
_RUNS = "runs"


def safe_relative(root: Path, relative: str) -> Path:
    """`root / relative`, refusing absolute paths and anything that escapes `root`."""
    candidate = Path(relative)
    if candidate.is_absolute() or ".." in candidate.parts or relative.strip() == "":
        raise ArtifactCorrupt(f"path '{relative}' escapes the artifact directory {root}")
    resolved = (root / candidate).resolve()
    if not resolved.is_relative_to(root.resolve()):
        raise ArtifactCorrupt(f"path '{relative}' escapes the artifact directory {root}")
    return root / candidate


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


def _fsync_dir(path: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _fsync_file(path: Path) -> None:
    with path.open("rb") as f:
        os.fsync(f.fileno())


class ArtifactStore:
    """Content-keyed artifacts on a local (or mounted shared) filesystem."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)

    # -- layout -------------------------------------------------------------------------
    def artifact_dir(self, stage: str, key: str) -> Path:
        if not stage.isidentifier() or not all(c in "0123456789abcdef" for c in key) or not key:
            raise StoreError(f"invalid artifact address {stage}/{key}")
        return self.root / stage / key

    def lock(self, stage: str, key: str) -> FileLock:
        """The per-key lock; a second process computing the same key waits on it."""
        locks = self.root / _LOCKS
        locks.mkdir(parents=True, exist_ok=True)
        return FileLock(str(locks / f"{stage}-{key}.lock"))

    # -- reading ------------------------------------------------------------------------
    def get(self, stage: str, key: str) -> ArtifactRef | None:
        """The artifact if it is committed (manifest present and parseable), else None."""
        path = self.artifact_dir(stage, key)
        manifest_path = path / MANIFEST
        try:
            manifest = json.loads(manifest_path.read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as err:
            raise ArtifactCorrupt(f"{manifest_path}: unreadable manifest ({err})") from err
        if manifest.get("key") != key or manifest.get("stage") != stage:
            raise ArtifactCorrupt(f"{manifest_path}: manifest names another artifact")
        return ArtifactRef(stage, key, path, manifest)

    def verify(self, ref: ArtifactRef) -> None:
        """Check every file's size and sha256 and the key against the recipe."""
        verify_artifact_dir(ref.path, ref.manifest)

    def iter_artifacts(self) -> Iterator[ArtifactRef]:
        """Every committed artifact, sorted by stage then key."""
        if not self.root.is_dir():
            return
        for stage_dir in sorted(p for p in self.root.iterdir() if p.is_dir()):
            if stage_dir.name.startswith(".") or stage_dir.name == _RUNS:
                continue
            for key_dir in sorted(p for p in stage_dir.iterdir() if p.is_dir()):
                with contextlib.suppress(StoreError):
                    ref = self.get(stage_dir.name, key_dir.name)
                    if ref is not None:
                        yield ref

    def find(self, stage_or_key: str) -> ArtifactRef:
        """An artifact by key (or unique key prefix), or the newest artifact of a stage."""
        refs = list(self.iter_artifacts())
        by_stage = [r for r in refs if r.stage == stage_or_key]
        if by_stage:
            return max(by_stage, key=lambda r: str(r.manifest.get("created_at", "")))
        by_key = [r for r in refs if r.key.startswith(stage_or_key)]
        if len(by_key) == 1:
            return by_key[0]
        if len(by_key) > 1:
            raise StoreError(f"key prefix '{stage_or_key}' is ambiguous ({len(by_key)} artifacts)")
        raise StoreError(f"no artifact for stage or key '{stage_or_key}' in {self.root}")

    # -- writing ------------------------------------------------------------------------
    def commit(
        self,
        stage: str,
        key: str,
        build: Callable[[Path], Mapping[str, Any]],
        manifest_extra: Mapping[str, Any],
    ) -> ArtifactRef:
        """Build an artifact atomically; reuse it if another process committed it first.

        Args:
            build: writes the output files into the given empty temporary directory and
                returns extra manifest fields (e.g. row counts). If it raises, nothing
                becomes visible.
            manifest_extra: recipe, config, versions... merged into the manifest.
        """
        with self.lock(stage, key):
            existing = self.get(stage, key)
            if existing is not None:
                return existing
            tmp = self.root / _TMP / f"{stage}-{key[:16]}-{os.getpid()}-{uuid.uuid4().hex[:8]}"
            tmp.mkdir(parents=True)
            try:
                t0 = time.perf_counter()
                extra = dict(build(tmp))
                files = {}
                for f in sorted(p for p in tmp.rglob("*") if p.is_file()):
                    _fsync_file(f)
                    rel = f.relative_to(tmp).as_posix()
                    files[rel] = {"sha256": sha256_file(f), "size": f.stat().st_size}
                manifest = {
                    **dict(manifest_extra),
                    **extra,
                    "stage": stage,
                    "key": key,
                    "files": files,
                    "store_format": STORE_FORMAT_VERSION,
                    "build_seconds": round(time.perf_counter() - t0, 3),
                    "created_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                }
                (tmp / MANIFEST).write_text(json.dumps(manifest, indent=2, sort_keys=True))
                _fsync_file(tmp / MANIFEST)
                _fsync_dir(tmp)
                final = self.artifact_dir(stage, key)
                final.parent.mkdir(parents=True, exist_ok=True)
                tmp.rename(final)
                _fsync_dir(final.parent)
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
        ref = self.get(stage, key)
        if ref is None:  # pragma: no cover - rename succeeded, so this cannot happen
            raise StoreError(f"{stage}/{key}: commit vanished")
        return ref

    def import_dir(self, source: Path, manifest: Mapping[str, Any]) -> ArtifactRef:
        """Adopt an already verified artifact directory (used by `pull`), atomically."""
        stage, key = str(manifest["stage"]), str(manifest["key"])

        def copy(tmp: Path) -> Mapping[str, Any]:
            for rel in manifest["files"]:
                dst = safe_relative(tmp, rel)
                dst.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(safe_relative(source, rel), dst)
            return {}

        keep = {k: v for k, v in manifest.items() if k not in ("files", "build_seconds")}
        ref = self.commit(stage, key, copy, keep)
        verify_artifact_dir(ref.path, ref.manifest)
        return ref

    # -- runs and garbage collection ----------------------------------------------------
    def record_run(self, run_id: str, record: Mapping[str, Any]) -> None:
        """Remember which artifacts a run used (gc keeps what any run record references)."""
        runs = self.root / _RUNS
        runs.mkdir(parents=True, exist_ok=True)
        tmp = runs / f".{run_id}.{os.getpid()}.tmp"
        tmp.write_text(json.dumps(record, indent=2, sort_keys=True))
        tmp.replace(runs / f"{run_id}.json")

    def run_records(self) -> list[dict[str, Any]]:
        """All run records, oldest first."""
        runs = self.root / _RUNS
        if not runs.is_dir():
            return []
        records = []
        for f in runs.glob("*.json"):
            with contextlib.suppress(OSError, ValueError):
                records.append(json.loads(f.read_text()))
        return sorted(records, key=lambda r: str(r.get("updated_at", "")))

    def gc(self, *, dry_run: bool = False, stale_tmp_s: float = 3600.0) -> dict[str, Any]:
        """Remove artifacts no run record references, and stale temporaries.

        Returns:
            {"removed": [stage/key...], "kept": int, "tmp_removed": int, "bytes_freed": int}
        """
        referenced = {
            (stage, info["key"])
            for record in self.run_records()
            for stage, info in record.get("stages", {}).items()
        }
        removed, kept, freed = [], 0, 0
        for ref in list(self.iter_artifacts()):
            if (ref.stage, ref.key) in referenced:
                kept += 1
                continue
            size = sum(int(f["size"]) for f in ref.manifest.get("files", {}).values())
            removed.append(f"{ref.stage}/{ref.key}")
            freed += size
            if not dry_run:
                shutil.rmtree(ref.path, ignore_errors=True)
        tmp_removed = 0
        tmp_root = self.root / _TMP
        if tmp_root.is_dir():
            now = time.time()
            for t in tmp_root.iterdir():
                if now - t.stat().st_mtime > stale_tmp_s:
                    tmp_removed += 1
                    if not dry_run:
                        shutil.rmtree(t, ignore_errors=True)
        return {"removed": removed, "kept": kept, "tmp_removed": tmp_removed, "bytes_freed": freed}


def verify_artifact_dir(path: Path, manifest: Mapping[str, Any]) -> None:
    """Raise `ArtifactCorrupt` unless every listed file matches and the key matches the recipe."""
    recipe = manifest.get("recipe")
    if recipe is not None and recipe_key(recipe) != manifest.get("key"):
        raise ArtifactCorrupt(f"{path}: key does not match the manifest's recipe")
    files = manifest.get("files")
    if not isinstance(files, Mapping):
        raise ArtifactCorrupt(f"{path}: manifest lists no files")
    for rel, info in files.items():
        f = safe_relative(path, rel)
        if not f.is_file():
            raise ArtifactCorrupt(f"{path}: missing file '{rel}'")
        if f.stat().st_size != int(info["size"]):
            raise ArtifactCorrupt(
                f"{path}: '{rel}' has size {f.stat().st_size}, expected {info['size']}"
            )
        if sha256_file(f) != info["sha256"]:
            raise ArtifactCorrupt(f"{path}: '{rel}' sha256 does not match its manifest")
