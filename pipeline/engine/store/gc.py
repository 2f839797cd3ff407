"""`sonarmap gc`: what the store keeps, and the leftovers it heals.

Kept: every artifact a run record (or a pull's record) names or a live run's lease holds
(`sonarmap.pipeline.engine.store.leases`), and everything reachable from those through their
manifests' `input_artifacts` (a `train` model keeps the keyframes and features of
every dataset it learnt from, so `push train` still finds them). Runs record each
stage as it commits, so an interrupted run's finished stages are kept too.

Races with a live run: the scan of artifacts comes first, then the leases, then the
run records (a run writes its final record before dropping its lease, and claims an
address in its lease before it commits or reads it). Each removal happens under the
artifact's key lock and looks again at leases and records if either folder changed
since; an artifact whose directory is newer than the start of `gc` is never removed.

Nothing is removed from a folder that is not a store (none of `_store_marks` and no
artifact: a mistyped `--store`), nor while a run record cannot be read (it may name what
would go): both are refused with one line naming the folder or the record.

Removed:
- unreferenced artifacts;
- directories that are not artifacts: no manifest (deleted by hand, or a crash of an
  older version), or a manifest that does not validate;
- with `broken=True`, artifacts whose files or work units no longer match their
  manifest's sha256 (or are missing);
- leftovers of killed processes: `.tmp/<name>-<pid>-<hex>` commits, pulls and discards,
  `runs/.<id>.<pid>.tmp`, `.cache/fingerprints.tmp<pid>` and `.leases/.<pid>-<hex>.*.tmp`,
  once that pid is gone; leases whose owner is gone (their flock is free).
  Temporaries of live processes are never touched; names without a pid (older
  versions) go when older than `stale_tmp_s`.
- per-keyframe work units (`sonarmap.pipeline.engine.store.units`, computed here or
  pulled) that no kept artifact's manifest lists; none while a run is live (its units are listed only once it commits)
  and none written after `gc` started.
Every removal is a rename out of sight first, so a reader never sees half a directory.
"""

from __future__ import annotations

import contextlib
import re
import time
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, Protocol

from filelock import BaseFileLock, Timeout

from sonarmap.pipeline.engine.errors import StoreError
from sonarmap.pipeline.engine.store.artifact import PULL_CACHE, ArtifactRef, Problem
from sonarmap.pipeline.engine.store.disk import delete_entry
from sonarmap.pipeline.engine.store.integrity import verify_artifact_dir
from sonarmap.pipeline.engine.store.leases import LEASES, pid_alive, scan_leases
from sonarmap.pipeline.engine.store.manifest import ADDRESS_PATTERN
from sonarmap.pipeline.engine.store.units import (
    PULLED_UNITS,
    UNITS,
    iter_pulled_unit_files,
    iter_unit_files,
    unit_entries,
    verify_units,
)


class CollectedStore(Protocol):
    """What `collect` needs of the store (`sonarmap.pipeline.engine.store.artifact_store.ArtifactStore`): named
    here so the collector does not import the store that calls it."""

    root: Path

    def lock(self, stage: str, key: str) -> BaseFileLock: ...
    def run_records(self, *, strict: bool = False) -> list[dict[str, Any]]: ...
    def scan(self) -> Iterator[ArtifactRef | Problem]: ...
    def tmp_path(self, prefix: str) -> Path: ...


__all__ = ["collect", "reachable"]

_TMP_PID = re.compile(r"-(\d+)-[0-9a-f]{8,12}$")
_RUN_TMP_PID = re.compile(r"^\..+\.(\d+)\.tmp$")
_FINGERPRINT_TMP_PID = re.compile(r"^fingerprints\.tmp(\d+)$")
_TICK_NS = 50_000_000  # coarser than any filesystem's timestamp granularity we meet
_NEVER = re.compile(r"(?!)")  # pull-cache files carry no pid: their age decides
_LEASE_TMP_PID = re.compile(r"^\.(\d+)-[0-9a-f]{12}\.(?:lock|json)\.tmp$")


def _upstream(ref: ArtifactRef) -> Iterator[tuple[str, str]]:
    addresses = ref.manifest.get("input_artifacts") or {
        name: f"{name.split('.', 1)[0]}/{key}"
        for name, key in ref.manifest.get("inputs", {}).items()
    }
    for address in addresses.values():
        if re.fullmatch(ADDRESS_PATTERN, address):
            stage, _, key = address.partition("/")
            yield stage, key


def _roots(records: Iterable[Mapping[str, Any]]) -> set[tuple[str, str]]:
    roots = set()
    for record in records:
        for address in record.get("artifacts") or ():  # a pull's record
            if isinstance(address, str) and re.fullmatch(ADDRESS_PATTERN, address):
                stage, _, key = address.partition("/")
                roots.add((stage, key))
        stages = record.get("stages")
        if not isinstance(stages, Mapping):
            continue
        for stage, info in stages.items():
            if isinstance(info, Mapping) and isinstance(info.get("key"), str):
                roots.add((str(stage), info["key"]))
    return roots


def reachable(
    refs: Mapping[tuple[str, str], ArtifactRef], roots: Iterable[tuple[str, str]]
) -> set[tuple[str, str]]:
    """The roots present in `refs` and every artifact upstream of them."""
    keep: set[tuple[str, str]] = set()
    todo = [r for r in roots if r in refs]
    while todo:
        item = todo.pop()
        if item in keep:
            continue
        keep.add(item)
        todo.extend(u for u in _upstream(refs[item]) if u in refs and u not in keep)
    return keep


class _Roots:
    """What must stay: leases' and run records' addresses and their upstream closure,
    looked at again whenever the `.leases` or `runs` folder has changed."""

    def __init__(self, store: CollectedStore, refs: Mapping[tuple[str, str], ArtifactRef]) -> None:
        self.store, self.refs = store, refs
        self.live_runs = 0
        self.keep: set[tuple[str, str]] = set()
        self._seen: tuple[int, int] | None = None
        self._read_ns = 0

    def _stamp(self) -> tuple[int, int]:
        stamps = []
        for name in (LEASES, "runs"):
            try:
                stamps.append((self.store.root / name).stat().st_mtime_ns)
            except OSError:
                stamps.append(0)
        return stamps[0], stamps[1]

    def refresh(self, *, prune: bool = False) -> int:
        """Read leases, then records; returns how many stale leases were removed."""
        self._seen = self._stamp()
        self._read_ns = time.time_ns()
        leases = scan_leases(self.store.root, prune=prune)  # before the records: see above
        records = self.store.run_records(strict=True)  # unreadable: remove nothing
        self.live_runs = leases.live
        self.keep = reachable(self.refs, leases.addresses | _roots(records))
        return leases.stale_removed

    def holds(self, address: tuple[str, str]) -> bool:
        """Whether `address` must stay, looking again if a run may have changed that."""
        # A folder changed within a clock tick of the last read may have changed again
        # without its mtime moving: such a stamp proves nothing, so read again.
        unsure = self._seen is None or max(self._seen) >= self._read_ns - _TICK_NS
        if unsure or self._stamp() != self._seen:
            self.refresh()
        return address in self.keep


def _remove_dir(
    store: CollectedStore,
    stage: str,
    key: str,
    path: Path,
    roots: _Roots | None = None,
    started_ns: int = 0,
) -> bool:
    """Rename out of sight, then delete; skipped while another process holds the key,
    when a run claimed it meanwhile, or when it was committed after `gc` started."""
    try:
        with store.lock(stage, key).acquire(timeout=0.5):
            if not path.exists():
                return False
            if roots is not None and roots.holds((stage, key)):
                return False
            with contextlib.suppress(OSError):
                if path.stat().st_mtime_ns >= started_ns > 0:
                    return False
            trash = store.tmp_path(f"gc-{stage}")
            trash.parent.mkdir(parents=True, exist_ok=True)
            path.rename(trash)
    except Timeout:
        return False
    delete_entry(trash)  # a symbolic link is unlinked, not what it leads to
    return True


def _leftovers(store: CollectedStore, stale_tmp_s: float) -> list[Path]:
    """Temporaries whose owner is gone (or, without a pid in the name, are old)."""
    found: list[Path] = []
    now = time.time()
    patterns = (
        (store.root / ".tmp", _TMP_PID, True),
        (store.root / "runs", _RUN_TMP_PID, False),
        (store.root / ".cache", _FINGERPRINT_TMP_PID, False),
        (store.root / LEASES, _LEASE_TMP_PID, False),
        (store.root / PULL_CACHE, _NEVER, True),
    )
    for folder, pattern, old_without_pid in patterns:
        if not folder.is_dir():
            continue
        for entry in sorted(folder.iterdir()):
            match = pattern.search(entry.name)
            if match is not None:
                if not pid_alive(int(match.group(1))):
                    found.append(entry)
                continue
            with contextlib.suppress(OSError):
                if old_without_pid and now - entry.lstat().st_mtime > stale_tmp_s:
                    found.append(entry)
    return found


def _store_marks(store: CollectedStore) -> bool:
    """Whether the store's root holds a folder or file only a store writes: run records,
    leases, key locks, commits in progress, the dataset fingerprint cache (a run killed
    early leaves only those), work units, a pull's resume cache. Without any, only an
    artifact with a manifest (a pulled store may have no runs) makes it a store."""
    marks = ("runs", LEASES, ".locks", ".tmp", UNITS, PULLED_UNITS, PULL_CACHE)
    if any((store.root / name).is_dir() for name in marks):
        return True
    return any((store.root / ".cache").glob("fingerprints*"))  # a run's first write


def _dir_bytes(path: Path) -> int:
    with contextlib.suppress(OSError):
        return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
    return 0


def _size(ref: ArtifactRef) -> int:
    return sum(int(f["size"]) for f in ref.manifest["files"].values())


def collect(
    store: CollectedStore,
    *,
    dry_run: bool = False,
    broken: bool = False,
    stale_tmp_s: float = 3600.0,
) -> dict[str, Any]:
    """Garbage-collect `store` (see the module docstring for what goes).

    Returns:
        {"removed": [stage/key...], "broken": ["stage/key: reason"...], "kept": int,
         "tmp_removed": int, "bytes_freed": int, "live_runs": int, "stale_leases": int};
        `removed` includes the broken ones.
    """
    marked = _store_marks(store)
    # Writers without a lease (a pull in progress) are covered by this: what they
    # rename into place after now is never removed by this pass.
    started_ns = time.time_ns()
    refs: dict[tuple[str, str], ArtifactRef] = {}
    bad: list[Problem] = []
    for item in store.scan():
        if not isinstance(item, ArtifactRef):
            bad.append(item)
            continue
        marked = True  # an artifact with a manifest
        if broken:
            try:
                verify_artifact_dir(item.path, item.manifest)
                verify_units(store.root, item.stage, item.manifest)
            except StoreError as err:
                reason = str(err).removeprefix(f"{item.path}: ")
                bad.append(Problem(item.stage, item.key, item.path, reason))
                continue
        refs[(item.stage, item.key)] = item
    if not marked:  # before any removal
        raise StoreError(
            f"{store.root}: not a sonarmap store (no runs folder, no artifact with a"
            " manifest); gc removes nothing there (check --store)"
        )
    roots = _Roots(store, refs)
    stale_leases = roots.refresh(prune=not dry_run)
    keep = set(roots.keep)
    removed, broken_lines, freed = [], [], 0
    for problem in bad:
        broken_lines.append(str(problem))
        size = _dir_bytes(problem.path)
        if dry_run or _remove_dir(store, problem.stage, problem.key, problem.path):
            removed.append(f"{problem.stage}/{problem.key}")
            freed += size
    for address, ref in refs.items():
        if address in keep:
            continue
        if dry_run or _remove_dir(store, ref.stage, ref.key, ref.path, roots, started_ns):
            removed.append(f"{ref.stage}/{ref.key}")
            freed += _size(ref)
    kept_refs = [ref for address, ref in refs.items() if address in keep]
    units_removed, units_freed = _collect_units(store, kept_refs, roots, dry_run, started_ns)
    freed += units_freed
    leftovers = _leftovers(store, stale_tmp_s)
    if not dry_run:
        for path in leftovers:
            delete_entry(path)
    return {
        "removed": removed,
        "broken": broken_lines,
        "kept": len(keep),
        "tmp_removed": len(leftovers),
        "bytes_freed": freed,
        "live_runs": roots.live_runs,
        "stale_leases": stale_leases,
        "units_removed": units_removed,
    }


def _collect_units(
    store: CollectedStore,
    kept: Iterable[ArtifactRef],
    roots: _Roots,
    dry_run: bool,
    started_ns: int,
) -> tuple[int, int]:
    """Remove the units no kept artifact lists (computed here: by key; pulled: by
    sha256): (how many, bytes)."""
    listed: set[tuple[str, str]] = set()
    for ref in kept:
        with contextlib.suppress(StoreError):  # a malformed list keeps nothing extra
            for key, entry in unit_entries(ref.manifest, ref.stage).items():
                listed |= {(ref.stage, key), (ref.stage, entry["sha256"])}
    removed = freed = 0
    files = [*iter_unit_files(store.root), *iter_pulled_unit_files(store.root)]
    for stage, key, path in files:
        if (stage, key) in listed:
            continue
        roots.holds(("", ""))  # reads leases again if a run started meanwhile
        if roots.live_runs:
            break
        try:
            st = path.lstat()
            if st.st_mtime_ns >= started_ns:
                continue
            if not dry_run:
                path.unlink()
        except OSError:
            continue
        removed += 1
        freed += st.st_size
    return removed, freed
