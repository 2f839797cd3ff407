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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from filelock import FileLock

from sonarmap.pipeline.engine.errors import ArtifactCorrupt, StoreError
from sonarmap.pipeline.engine.hashing import STORE_FORMAT_VERSION, sha256_file
from sonarmap.pipeline.engine.store.artifact import ArtifactRef, Problem, safe_relative
from sonarmap.pipeline.engine.store.commit_gate import NEVER_CLOSED, CommitGate
from sonarmap.pipeline.engine.store.disk import disk_error, fsync_dir, fsync_file
from sonarmap.pipeline.engine.store.integrity import recovery_hint, verify_artifact_dir, verify_file
from sonarmap.pipeline.engine.store.manifest import read_manifest
from sonarmap.pipeline.engine.store.units import UNITS, verify_units

__all__ = [
    "MANIFEST",
    "ArtifactRef",
    "ArtifactStore",
    "Problem",
    "Staging",
    "recovery_hint",
    "safe_relative",
    "verify_artifact_dir",
    "verify_file",
]

log = logging.getLogger(__name__)
MANIFEST = "manifest.json"
_TMP = ".tmp"
_LOCKS = ".locks"
_RUNS = "runs"


@dataclass
class Staging:
    """An artifact being committed under its key's lock (`ArtifactStore.staging`).

    Attributes:
        tmp: the empty temporary directory to write the files into (None: another
            process committed the artifact first; it is reused).
        extra: manifest fields the writer adds (e.g. row counts).
    """

    store: ArtifactStore
    stage: str
    key: str
    tmp: Path | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def committed(self) -> ArtifactRef:
        """The artifact, once the staging block has left."""
        ref = self.store.get(self.stage, self.key)
        if ref is None:  # pragma: no cover - committed or found under the lock
            raise StoreError(f"{self.stage}/{self.key}: commit vanished")
        return ref


class ArtifactStore:
    """Content-keyed artifacts on a local (or mounted shared) filesystem."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        if self.root.exists() and not self.root.is_dir():  # every command would misread it
            raise StoreError(f"{self.root}: a file, not a store folder (check --store)")

    # -- layout -------------------------------------------------------------------------
    def artifact_dir(self, stage: str, key: str) -> Path:
        if not stage.isidentifier() or not all(c in "0123456789abcdef" for c in key) or not key:
            raise StoreError(f"invalid artifact address {stage}/{key}")
        return self.root / stage / key

    def tmp_path(self, prefix: str) -> Path:
        """A fresh temporary path in the store; its name carries our pid so `gc` can
        tell a live commit from a killed one."""
        return self.root / _TMP / f"{prefix}-{os.getpid()}-{uuid.uuid4().hex[:8]}"

    def lock(self, stage: str, key: str) -> FileLock:
        """The per-key lock; a second process computing the same key waits on it."""
        locks = self.root / _LOCKS
        locks.mkdir(parents=True, exist_ok=True)
        return FileLock(str(locks / f"{stage}-{key}.lock"))

    # -- reading ------------------------------------------------------------------------
    def get(self, stage: str, key: str) -> ArtifactRef | None:
        """The artifact if it is committed (manifest present and valid), else None."""
        try:
            return self._load(stage, key)
        except ArtifactCorrupt as err:
            raise ArtifactCorrupt(f"{err}; {recovery_hint(stage)}") from err

    def _load(self, stage: str, key: str) -> ArtifactRef | None:
        path = self.artifact_dir(stage, key)
        if path.is_symlink():
            # The store writes directories, never links: a link may lead anywhere, and
            # its files would pass every check made inside it.
            raise ArtifactCorrupt(
                f"{path}: a symbolic link, not an artifact directory (the store writes none)"
            )
        manifest_path = path / MANIFEST
        try:
            model, manifest = read_manifest(manifest_path)
        except FileNotFoundError:
            return None
        if model.key != key or model.stage != stage:
            raise ArtifactCorrupt(f"{manifest_path}: manifest names another artifact")
        return ArtifactRef(stage, key, path, manifest)

    def verify(self, ref: ArtifactRef) -> None:
        """Check every file's size and sha256 and the key against the recipe."""
        try:
            verify_artifact_dir(ref.path, ref.manifest)
            # the units of the store holding `ref` (a fallback's, for push)
            verify_units(ref.path.parent.parent, ref.stage, ref.manifest)
        except ArtifactCorrupt as err:
            raise ArtifactCorrupt(f"{err}; {recovery_hint(ref.stage)}") from err

    def scan(self) -> Iterator[ArtifactRef | Problem]:
        """Every directory under a stage folder: a committed artifact or a `Problem`.

        A directory without a manifest (its manifest deleted, or copied in by hand) is
        not an artifact; neither is one whose manifest does not validate. Names the
        store could never have written (not a stage identifier, not a 64-digit hex key)
        are not ours and are left alone (a user's `exports/2024/` is no artifact), and
        so is a stage folder that is a symbolic link (it may lead anywhere).
        """
        if not self.root.is_dir():
            return
        for stage_dir in sorted(p for p in self.root.iterdir() if p.is_dir()):
            if not stage_dir.name.isidentifier() or stage_dir.name in (_RUNS, UNITS):
                continue
            if stage_dir.is_symlink():
                continue
            for key_dir in sorted(p for p in stage_dir.iterdir() if p.is_dir()):
                stage, key = stage_dir.name, key_dir.name
                if len(key) != 64 or key.strip("0123456789abcdef"):
                    continue
                try:
                    ref = self._load(stage, key)
                except StoreError as err:
                    yield Problem(stage, key, key_dir, str(err).removeprefix(f"{key_dir}/"))
                    continue
                yield ref if ref is not None else Problem(stage, key, key_dir, "no manifest")

    def iter_artifacts(self) -> Iterator[ArtifactRef]:
        """Every committed artifact, sorted by stage then key."""
        for item in self.scan():
            if isinstance(item, ArtifactRef):
                yield item

    def find(self, stage_or_key: str) -> ArtifactRef:
        """An artifact by key (or unique key prefix), or the newest artifact of a stage."""
        items = list(self.scan())
        refs = [r for r in items if isinstance(r, ArtifactRef)]
        by_stage = [r for r in refs if r.stage == stage_or_key]
        if by_stage:
            return max(by_stage, key=lambda r: str(r.manifest.get("created_at", "")))
        by_key = [r for r in refs if r.key.startswith(stage_or_key)]
        if len(by_key) == 1:
            return by_key[0]
        if len(by_key) > 1:
            raise StoreError(f"key prefix '{stage_or_key}' is ambiguous ({len(by_key)} artifacts)")
        bad = [
            p
            for p in items
            if isinstance(p, Problem) and stage_or_key in (p.stage, p.key[: len(stage_or_key)])
        ]
        if bad:
            raise ArtifactCorrupt(f"{bad[0]}; {recovery_hint(bad[0].stage)}")
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
        return self.commit_or_reuse(stage, key, build, manifest_extra)[0]

    def commit_or_reuse(
        self,
        stage: str,
        key: str,
        build: Callable[[Path], Mapping[str, Any]],
        manifest_extra: Mapping[str, Any],
    ) -> tuple[ArtifactRef, bool]:
        """`commit`, also saying whether the artifact was reused (True) or built here."""
        with self.staging(stage, key, manifest_extra) as slot:
            if slot.tmp is not None:
                slot.extra = dict(build(slot.tmp))
        return slot.committed(), slot.tmp is None

    @contextlib.contextmanager
    def staging(
        self,
        stage: str,
        key: str,
        manifest_extra: Mapping[str, Any],
        gate: CommitGate = NEVER_CLOSED,
    ) -> Iterator[Staging]:
        """Hold the key's lock; the caller writes the artifact's files into `slot.tmp`
        (None: another process committed it first, reuse it) and sets `slot.extra`
        (manifest fields). On leaving, the files are fsynced, the manifest written
        last and the directory renamed into place; on an exception nothing is visible.

        An OSError (full disk, read-only store, name too long) becomes a one-line
        `StoreError` naming the path; the temporary directory goes.
        """
        slot = Staging(self, stage, key)
        try:
            with self.lock(stage, key):
                if self.get(stage, key) is not None:
                    yield slot
                    return
                slot.tmp = self.tmp_path(f"{stage}-{key[:16]}")
                with gate.staging(slot.tmp):
                    slot.tmp.mkdir(parents=True)
                    try:
                        t0 = time.perf_counter()
                        yield slot
                        with gate.committing(stage, key):
                            self._finish(slot.tmp, stage, key, {**manifest_extra, **slot.extra}, t0)
                    except BaseException:
                        shutil.rmtree(slot.tmp, ignore_errors=True)
                        raise
        except OSError as err:
            raise disk_error(err, self.artifact_dir(stage, key)) from err

    def _finish(self, tmp: Path, stage: str, key: str, extra: Mapping[str, Any], t0: float) -> None:
        files = {}
        for f in sorted(p for p in tmp.rglob("*") if p.is_file()):
            fsync_file(f)
            rel = f.relative_to(tmp).as_posix()
            files[rel] = {"sha256": sha256_file(f), "size": f.stat().st_size}
        manifest = {
            **dict(extra),
            "stage": stage,
            "key": key,
            "files": files,
            "store_format": STORE_FORMAT_VERSION,
            "build_seconds": round(time.perf_counter() - t0, 3),
            "created_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        }
        (tmp / MANIFEST).write_text(json.dumps(manifest, indent=2, sort_keys=True))
        fsync_file(tmp / MANIFEST)
        fsync_dir(tmp)
        final = self.artifact_dir(stage, key)
        final.parent.mkdir(parents=True, exist_ok=True)
        self._clear_non_artifact(final)
        tmp.rename(final)
        fsync_dir(final.parent)

    def _clear_non_artifact(self, final: Path) -> None:
        """Move a manifest-less directory at `final` aside (we hold its key's lock).

        Such a directory is not an artifact (its manifest was deleted); left in place it
        would make the rename fail with "Directory not empty" on every later run.
        """
        if not final.exists():
            return
        log.warning("%s has no manifest: replacing it", final)
        trash = self.tmp_path("replaced")
        final.rename(trash)
        shutil.rmtree(trash, ignore_errors=True)

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
        """Remember which artifacts a run used (gc keeps what any run record references).

        An OSError becomes a one-line `StoreError`; the previous record stays whole.
        """
        runs = self.root / _RUNS
        tmp = runs / f".{run_id}.{os.getpid()}.tmp"
        try:
            runs.mkdir(parents=True, exist_ok=True)
            tmp.write_text(json.dumps(record, indent=2, sort_keys=True))
            tmp.replace(runs / f"{run_id}.json")
        except BaseException as err:
            with contextlib.suppress(OSError):
                tmp.unlink()
            if isinstance(err, OSError):
                raise disk_error(err, runs / f"{run_id}.json") from err
            raise

    def run_record(self, run_id: str) -> dict[str, Any] | None:
        """The record of one run, or None (absent or unreadable)."""
        with contextlib.suppress(OSError, ValueError):
            record = json.loads((self.root / _RUNS / f"{run_id}.json").read_text())
            if isinstance(record, dict):
                return record
        return None

    def run_records(self, *, strict: bool = False) -> list[dict[str, Any]]:
        """All run records, oldest first.

        A record that cannot be read (empty, not JSON, not an object: a crash on a
        filesystem without fsync, a sync tool) is skipped, or with `strict` raises
        `StoreError` naming it: `gc` must not remove what such a record may name.
        A record removed meanwhile is skipped either way.
        """
        runs = self.root / _RUNS
        try:  # not a glob: it reads an unreadable folder, or a file, as an empty folder
            files = sorted(p for p in runs.iterdir() if p.suffix == ".json" and p.name[0] != ".")
        except FileNotFoundError:
            return []
        except OSError as err:  # gc would remove every artifact such records may name
            if strict:
                raise StoreError(f"{runs}: unreadable run records ({_reason(err)})") from err
            return []
        records = []
        for f in files:
            try:
                text = f.read_bytes()
                record = json.loads(text) if text.strip() else None
            except FileNotFoundError:
                continue
            except (OSError, ValueError) as err:
                if strict:
                    raise StoreError(f"{f}: unreadable run record ({_reason(err)})") from err
                continue
            if record is None and strict:
                raise StoreError(f"{f}: unreadable run record (empty)")
            if isinstance(record, dict):
                records.append(record)
            elif strict:
                raise StoreError(f"{f}: unreadable run record (not a JSON object)")
        return sorted(records, key=lambda r: str(r.get("updated_at", "")))

    def gc(
        self, *, dry_run: bool = False, broken: bool = False, stale_tmp_s: float = 3600.0
    ) -> dict[str, Any]:
        """Remove unreferenced artifacts, non-artifacts and dead processes' leftovers.

        Returns:
            {"removed": [stage/key...], "broken": [...], "kept": int, "tmp_removed": int,
             "bytes_freed": int} (details in `sonarmap.pipeline.engine.store.gc.collect`).
        """
        from sonarmap.pipeline.engine.store.gc import collect

        return collect(self, dry_run=dry_run, broken=broken, stale_tmp_s=stale_tmp_s)


def _reason(err: BaseException) -> str:
    """An unreadable record's reason in a few words (an OSError's strerror, else the
    parser's first line)."""
    if isinstance(err, OSError) and err.strerror:
        return err.strerror
    text = str(err).splitlines()[0] if str(err) else type(err).__name__
    return text[:120] or "empty"
