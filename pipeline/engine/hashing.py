"""Canonical JSON, artifact keys and dataset fingerprints.

Key recipe (docs/architecture.md#keys): sha256 of the canonical JSON of stage name, stage version,
the stage's own resolved config section, the keys of its inputs, the schema version
and the store-format version, plus the dataset's content fingerprint for a stage that
reads the raw dataset. Never Python's salted `hash()`.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from filelock import FileLock

from sonarmap.pipeline.engine.errors import ConfigError, SourceError

__all__ = [
    "STORE_FORMAT_VERSION",
    "FingerprintCache",
    "canonical_json",
    "changed_file",
    "changed_while_read",
    "file_identities",
    "recipe_key",
    "sha256_file",
    "stage_recipe",
]

STORE_FORMAT_VERSION = 1
_CHUNK = 4 * 1024 * 1024


def _reject_nan(obj: Any, where: str = "") -> None:
    if isinstance(obj, float) and not math.isfinite(obj):
        raise ConfigError(f"{where or 'value'}: NaN/inf cannot be hashed")
    if isinstance(obj, Mapping):
        for k, v in obj.items():
            _reject_nan(v, f"{where}.{k}" if where else str(k))
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            _reject_nan(v, f"{where}[{i}]")


def canonical_json(obj: Any) -> bytes:
    """Sorted keys, no whitespace, floats as repr, NaN refused, UTF-8."""
    _reject_nan(obj)
    return json.dumps(
        obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False
    ).encode()


def recipe_key(recipe: Mapping[str, Any]) -> str:
    """sha256 hex digest of the canonical JSON of a key recipe."""
    return hashlib.sha256(canonical_json(recipe)).hexdigest()


def stage_recipe(
    *,
    stage: str,
    version: int,
    config: Mapping[str, Any],
    input_keys: Mapping[str, str],
    schema_version: int,
    dataset_fingerprint: str | None = None,
) -> dict[str, Any]:
    """The dict whose canonical JSON hash is the artifact key (also stored in the manifest)."""
    recipe: dict[str, Any] = {
        "stage": stage,
        "version": version,
        "config": dict(config),
        "inputs": dict(sorted(input_keys.items())),
        "schema_version": schema_version,
        "store_format": STORE_FORMAT_VERSION,
    }
    if dataset_fingerprint is not None:
        recipe["dataset"] = dataset_fingerprint
    return recipe


def sha256_file(path: Path) -> str:
    """Streaming sha256 of one file."""
    digest = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


Identity = tuple[tuple[str, tuple[int, ...]], ...]
"""Each file of a dataset with its `_stat_identity` at the time it was fingerprinted."""


def file_identities(parts: Sequence[Path]) -> Identity:
    """The stat identity of each file (`_stat_identity`), to tell later whether any changed."""
    return tuple((str(p), tuple(_stat_identity(p))) for p in parts)


class ChangedWhileRead(SourceError):
    """A dataset file changed after it was fingerprinted (`changed_while_read`)."""


def changed_while_read(path: str) -> SourceError:
    """The error of a dataset file that changed after it was fingerprinted: what was read
    is not what the keys name, so nothing is kept of it."""
    return ChangedWhileRead(
        f"{path}: changed while sonarmap read it (a recorder still writing it, or a copy"
        " replacing it): map it once it is closed, or as it grows with `sonarmap follow`"
    )


def changed_file(identity: Identity) -> str | None:
    """The first file whose stat identity is no longer the one recorded (None: none)."""
    for path, ident in identity:
        try:
            now = tuple(_stat_identity(Path(path)))
        except SourceError:
            return path
        if now != ident:
            return path
    return None


def _stat_identity(path: Path) -> list[int]:
    """What the fingerprint memo compares: size, mtime, ctime, inode and device.

    ctime is the kernel's own clock of the last write or metadata change (no call sets
    it), so an in-place rewrite that restores the size and the mtime (`cp -p`, `rsync -t`,
    `touch -d` onto the same inode) still changes the identity
    (docs/decisions/020-cached-run-imports.md)."""
    try:
        st = path.stat()
    except OSError as err:
        raise SourceError(f"{path}: cannot read dataset ({err.strerror})") from err
    return [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino, st.st_dev]


class FingerprintCache:
    """Content fingerprints of dataset files, memoised by path and stat identity
    (`_stat_identity`: size, mtime, ctime, inode, device).

    A 10 GB bag is hashed once; `status` and a cached run afterwards only stat it. A
    digest is remembered only when the file's identity is the same after hashing as
    before (a file written meanwhile is hashed again next time), and never for a file
    whose timestamps have no sub-second part (a filesystem with coarse timestamps). The
    cache is a JSON file guarded by a file lock so concurrent runs do not clobber it.
    """

    def __init__(self, cache_file: Path, remember: bool = True) -> None:
        self._file = cache_file
        self._remember = remember  # False: read only (a planner never creates a store)
        self._lock = FileLock(str(cache_file) + ".lock")

    def _load(self) -> dict[str, Any]:
        """The remembered digests; the whole file or an entry of another shape than
        {"stat": [...], "sha256": 64 hex digits} is dropped (it is derived data: damaged,
        it costs a hash, never a failed run)."""
        try:
            data = json.loads(self._file.read_text())
        except (OSError, ValueError):
            return {}
        if not isinstance(data, dict):
            return {}
        return {
            path: entry
            for path, entry in data.items()
            if isinstance(entry, dict)
            and isinstance(entry.get("stat"), list)
            and isinstance(entry.get("sha256"), str)
            and re.fullmatch(r"[0-9a-f]{64}", entry["sha256"])
        }

    def file_digest(self, path: Path) -> str:
        """sha256 of `path`, from the cache when its stat identity is unchanged."""
        ident = _stat_identity(path)
        # Whole-second timestamps: a filesystem that keeps no finer time (FAT, some network
        # mounts), where a same-size rewrite within a second keeps every field. No memo.
        coarse = ident[1] % 10**9 == 0 and ident[2] % 10**9 == 0
        entry = None if coarse else self._load().get(str(path.resolve()))
        if entry and entry.get("stat") == ident:
            return str(entry["sha256"])
        digest = sha256_file(path)
        if coarse or not self._remember or _stat_identity(path) != ident:
            # Not remembered: coarse timestamps, or written while hashed (which content
            # the digest is of, no stat can say).
            return digest
        self._file.parent.mkdir(parents=True, exist_ok=True)
        with self._lock:
            data = self._load()
            data[str(path.resolve())] = {"stat": ident, "sha256": digest}
            tmp = self._file.with_suffix(f".tmp{os.getpid()}")
            tmp.write_text(json.dumps(data, sort_keys=True))
            tmp.replace(self._file)
        return digest

    def dataset_fingerprint(self, parts: Sequence[Path], root: Path) -> str:
        """Fingerprint of a dataset made of several files (a bag directory, split bags).

        Names are taken relative to `root` so moving the dataset keeps its fingerprint;
        a part that resolves outside `root` (a symlinked recording) is named by its file
        name alone.
        """
        root = root.resolve()
        resolved = [p.resolve() for p in parts]
        entries = sorted(
            (
                str(p.relative_to(root)) if p != root and p.is_relative_to(root) else p.name,
                self.file_digest(p),
            )
            for p in resolved
        )
        if len(entries) == 1:
            return entries[0][1]
        return hashlib.sha256(canonical_json(entries)).hexdigest()
