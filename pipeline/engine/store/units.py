"""Per-keyframe work units: content-addressed results a stage caches below its artifact.

A stage that declares `units=True` (`sonarmap.stages.base.Stage`) is handed a `UnitMemo`
under `inputs["units"]`: `get(key)` / `put(key, arrays)` of a dict of numpy arrays. The
stage computes the key itself from what the unit depends on (its version and config
fields, the keyframe's own content, the thresholds it uses); it never sees a path.

Layout: `<store>/units/<stage>/<key[:2]>/<key>`, written atomically (temporary file in
the store's `.tmp`, fsync, rename). A file is `MAGIC`, the raw sha256 of its key and its
payload, then the payload: a JSON line naming each array's dtype and shape, then the
arrays' raw bytes (plain numbers only: never a pickle, and the same arrays always give the
same bytes). The digest binds the file to its key: a unit whose digest does not match
(altered on disk, or another unit's file put in its place) is recomputed with a warning on
a local run; `verify_units` refuses it on `--verify`/`pull`. (Files of the first format,
`LEGACY_MAGIC`, digest the payload alone; they are still read.) `run --force STAGE`
recomputes the stage's units, reusing none.

The artifact a stage commits lists the units it was assembled from in its manifest
(`"units": {key: {"sha256", "size"}}`), so `gc` keeps the units of kept artifacts and removes the
rest, and `push`/`pull` carry them beside the artifact.

Units fetched by `pull` go to their own pool, `<store>/units-pulled/<stage>/<sha[:2]>/<sha>`
(named by their content's sha256), never under `units/`: a run reuses only units computed
in this store. A remote can vouch for its artifacts' files, not for what a unit of a given
key must hold, so a pulled unit serves only the pulled artifacts that list it (their
`--verify`, `push` on), and a remote's unit never enters a computation made here. Unit
files are plain files: a symbolic link or a device in either pool is refused, never read.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import stat
import uuid
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from sonarmap.pipeline.engine.errors import ArtifactCorrupt
from sonarmap.pipeline.engine.hashing import Identity, changed_file, changed_while_read

__all__ = [
    "MAGIC",
    "PULLED_UNITS",
    "UNITS",
    "UnitMemo",
    "copy_units",
    "decode_unit",
    "encode_unit",
    "file_entry",
    "held_unit_path",
    "install_pulled_unit",
    "iter_pulled_unit_files",
    "iter_unit_files",
    "pulled_unit_path",
    "unit_entries",
    "unit_path",
    "verify_units",
]

log = logging.getLogger(__name__)

UNITS = "units"
"""The store folder of the units (never a stage's folder: the store scan skips it)."""
PULLED_UNITS = "units-pulled"
"""The store folder of units fetched by `pull` (by sha256; not an identifier: no stage)."""
MAGIC = b"SMUNIT2\n"
LEGACY_MAGIC = b"SMUNIT1\n"
"""Units written before the digest took in the key: read, never written."""
_HEX = frozenset("0123456789abcdef")


def unit_path(root: Path, stage: str, key: str) -> Path:
    """Where unit `key` of `stage` lives in the store at `root` (refuses odd names)."""
    if not stage.isidentifier() or len(key) != 64 or not set(key) <= _HEX:
        raise ArtifactCorrupt(f"invalid unit address {stage[:40]}/{key[:70]}")
    return Path(root) / UNITS / stage / key[:2] / key


def pulled_unit_path(root: Path, stage: str, sha256: str) -> Path:
    """Where a pulled unit whose content has sha256 `sha256` lives in the store at `root`."""
    if not stage.isidentifier() or len(sha256) != 64 or not set(sha256) <= _HEX:
        raise ArtifactCorrupt(f"invalid unit address {stage[:40]}/{sha256[:70]}")
    return Path(root) / PULLED_UNITS / stage / sha256[:2] / sha256


def held_unit_path(root: Path, stage: str, key: str, entry: Mapping[str, Any]) -> Path:
    """The file of unit `key` an artifact lists with `entry` (its sha256): the pulled copy
    of that content when the store holds one, else the unit computed here."""
    pulled = pulled_unit_path(root, stage, str(entry["sha256"]))
    return pulled if pulled.exists() or pulled.is_symlink() else unit_path(root, stage, key)


def _read_plain(path: Path, where: str, size: int | None = None) -> bytes:
    """A unit file's bytes: refused (one line) when it is not a plain file, or when its
    size is not `size`; `FileNotFoundError` when absent."""
    st = path.lstat()
    if not stat.S_ISREG(st.st_mode):
        raise ArtifactCorrupt(
            f"{where}: not a plain file (a symbolic link or a device; the store writes plain files)"
        )
    if size is not None and st.st_size != size:
        raise ArtifactCorrupt(f"{where}: {st.st_size} bytes, its artifact's manifest says {size}")
    return path.read_bytes()


def encode_unit(arrays: Mapping[str, Any], key: str) -> bytes:
    """The file bytes of unit `key`: magic, sha256 of the key and the payload, the payload
    (a JSON header line naming each array's dtype and shape, then their raw bytes in that
    order)."""
    import numpy as np

    items = [(k, np.ascontiguousarray(arrays[k])) for k in sorted(arrays)]
    for name, a in items:
        if a.dtype.hasobject or a.dtype.kind not in "biuf":
            raise ValueError(f"unit array {name!r}: dtype {a.dtype} is not a plain number")
    header = [[k, a.dtype.str, list(a.shape)] for k, a in items]
    payload = json.dumps(header, separators=(",", ":")).encode() + b"\n"
    payload += b"".join(a.tobytes() for _, a in items)
    return MAGIC + hashlib.sha256(key.encode() + payload).digest() + payload


def decode_unit(data: bytes, where: str, key: str) -> dict[str, Any]:
    """The arrays of unit `key`'s file; `ArtifactCorrupt` (one line) if altered, another
    key's, or not a unit."""
    import numpy as np

    head = len(MAGIC) + 32
    magic = data[: len(MAGIC)]
    if magic not in (MAGIC, LEGACY_MAGIC) or len(data) < head:
        raise ArtifactCorrupt(f"{where}: not a work unit (no magic bytes)")
    payload = data[head:]
    signed = key.encode() + payload if magic == MAGIC else payload
    if hashlib.sha256(signed).digest() != data[len(MAGIC) : head]:
        raise ArtifactCorrupt(
            f"{where}: the unit's content does not match its digest (altered, or another"
            " unit's file)"
        )
    line, _, body = payload.partition(b"\n")
    try:
        out, offset = {}, 0
        for name, dtype, shape in json.loads(line):
            dt = np.dtype(dtype)
            if dt.hasobject or dt.kind not in "biuf":
                raise ValueError(f"dtype {dtype} is not a plain number")
            n = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
            if offset + n > len(body):
                raise ValueError("truncated")
            out[str(name)] = np.frombuffer(body, dt, n // dt.itemsize, offset).reshape(shape)
            offset += n
        if offset != len(body):
            raise ValueError("trailing bytes")
    except (TypeError, ValueError) as err:
        raise ArtifactCorrupt(f"{where}: unreadable unit ({err})") from err
    return out


def _write_atomic(root: Path, path: Path, data: bytes) -> None:
    tmp = Path(root) / ".tmp" / f"unit-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    tmp.parent.mkdir(parents=True, exist_ok=True)
    try:
        with tmp.open("wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.replace(path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def file_entry(data: bytes) -> dict[str, Any]:
    """What a manifest records of a unit file (as of an artifact's files)."""
    return {"sha256": hashlib.sha256(data).hexdigest(), "size": len(data)}


def install_pulled_unit(
    root: Path, stage: str, key: str, entry: Mapping[str, Any], data: bytes, where: str
) -> None:
    """Put a unit fetched by `pull` in the pulled pool, after checking it is the content
    its artifact lists (`entry`) and decodes; a unit computed here is never replaced."""
    if file_entry(data) != {"sha256": entry["sha256"], "size": entry["size"]}:
        raise ArtifactCorrupt(f"{where}: sha256 or size does not match the artifact's manifest")
    decode_unit(data, where, key)
    path = pulled_unit_path(root, stage, str(entry["sha256"]))
    if not path.exists():
        _write_atomic(root, path, data)


def unit_entries(manifest: Mapping[str, Any], where: str) -> dict[str, dict[str, Any]]:
    """The units a manifest lists, checked for shape (key: 64 hex, sha256 and size)."""
    raw = manifest.get("units") or {}
    if not isinstance(raw, Mapping):
        raise ArtifactCorrupt(f"{where}: manifest 'units' is not an object")
    out = {}
    for key, entry in raw.items():
        ok = isinstance(key, str) and len(key) == 64 and set(key) <= _HEX
        size = entry.get("size") if isinstance(entry, Mapping) else None
        ok = ok and isinstance(size, int) and not isinstance(size, bool) and size >= 0
        sha = entry.get("sha256") if isinstance(entry, Mapping) else None
        if not ok or not isinstance(sha, str) or len(sha) != 64 or not set(sha) <= _HEX:
            raise ArtifactCorrupt(f"{where}: manifest lists a malformed unit {str(key)[:70]!r}")
        out[key] = {"sha256": sha, "size": int(entry["size"])}
    return out


class UnitMemo:
    """A stage's get/put of its units in one store (picklable: a worker process gets it).

    Records the keys it handed out or stored (`used`, key -> the file's sha256 and size) and how
    many were found (`hits`) or computed (`misses`); `warnings` says which were altered.
    """

    def __init__(
        self,
        root: Path,
        stage: str,
        dataset: str = "",
        reuse: bool = True,
        identity: Identity = (),
    ) -> None:
        self.root, self.stage = Path(root), stage
        self.dataset = dataset
        """The content fingerprint of the run's dataset (for a stage reading it)."""
        self.identity = identity
        """Its files' stat identities when fingerprinted: a unit computed from a file
        changed since is not stored under that fingerprint."""
        self.reuse = reuse
        """False (`run --force STAGE`): every unit is computed again, none read."""
        self.used: dict[str, dict[str, Any]] = {}
        self.hits = 0
        self.misses = 0
        self.warnings: list[str] = []

    def get(self, key: str) -> dict[str, Any] | None:
        """The unit's arrays, or None (absent, or altered: then it is recomputed)."""
        path = unit_path(self.root, self.stage, key)
        where = f"unit {self.stage}/{key[:12]}"
        if not self.reuse:
            self.misses += 1
            return None
        try:
            data = _read_plain(path, where)
            arrays = decode_unit(data, where, key)
        except FileNotFoundError:
            self.misses += 1
            return None
        except ArtifactCorrupt as err:
            log.warning("%s: recomputing it", err)
            self.warnings.append(f"{err}: recomputed")
            self.misses += 1
            return None
        self.hits += 1
        self.used[key] = file_entry(data)
        return arrays

    def put(self, key: str, arrays: Mapping[str, Any]) -> None:
        """Store a computed unit (atomically; the same key always holds the same arrays)."""
        data = encode_unit(arrays, key)
        if self.identity and (changed := changed_file(self.identity)) is not None:
            raise changed_while_read(changed)
        _write_atomic(self.root, unit_path(self.root, self.stage, key), data)
        self.used[key] = file_entry(data)

    def manifest_fields(self) -> dict[str, Any]:
        """What the artifact's manifest records of its units."""
        fields = {
            "units": dict(sorted(self.used.items())),
            "units_reused": self.hits,
            "units_computed": self.misses,
        }
        if self.warnings:
            fields["unit_warnings"] = [
                f"{len(self.warnings)} work units altered on disk,"
                f" recomputed (first: {self.warnings[0]})"
            ]
        return fields


def iter_unit_files(root: Path, pool: str = UNITS) -> Iterator[tuple[str, str, Path]]:
    """Every unit file in one pool of the store (`UNITS`: (stage, key, path); `PULLED_UNITS`:
    (stage, sha256, path)); other names are left alone, and no link is followed."""
    base = Path(root) / pool
    if not base.is_dir() or base.is_symlink():
        return
    for stage_dir in sorted(p for p in base.iterdir() if p.is_dir() and not p.is_symlink()):
        for shard in sorted(p for p in stage_dir.iterdir() if p.is_dir() and not p.is_symlink()):
            for f in sorted(shard.iterdir()):
                key = f.name
                if len(key) == 64 and set(key) <= _HEX and key[:2] == shard.name:
                    yield stage_dir.name, key, f


def iter_pulled_unit_files(root: Path) -> Iterator[tuple[str, str, Path]]:
    """Every pulled unit file in the store: (stage, sha256, path)."""
    return iter_unit_files(root, PULLED_UNITS)


def verify_units(root: Path, stage: str, manifest: Mapping[str, Any]) -> None:
    """Raise `ArtifactCorrupt` unless every unit the manifest lists is present and matches
    both its own digest and the sha256 and size the manifest recorded."""
    art = f"artifact {stage}/{str(manifest.get('key'))[:12]}"
    for key, entry in unit_entries(manifest, art).items():
        path = held_unit_path(root, stage, key, entry)
        where = f"unit {stage}/{key[:12]} of {art}"
        try:
            data = _read_plain(path, where, entry["size"])
        except FileNotFoundError as err:
            raise ArtifactCorrupt(f"{where}: missing") from err
        if file_entry(data) != entry:
            raise ArtifactCorrupt(f"{where}: sha256 or size does not match the artifact's manifest")
        decode_unit(data, where, key)


def copy_units(src_root: Path, dest_root: Path, stage: str, manifest: Mapping[str, Any]) -> None:
    """Copy the units an artifact's manifest lists from the store at `src_root` to the one
    at `dest_root`, each checked (`verify_units`) first, so a copied artifact never lists a
    unit its new store lacks.

    Raises:
        ArtifactCorrupt: a listed unit is missing or altered in the source store.
    """
    verify_units(src_root, stage, manifest)
    for key, entry in unit_entries(manifest, f"artifact {stage}").items():
        src = held_unit_path(src_root, stage, key, entry)
        pulled = src.parent.parent.parent.name == PULLED_UNITS
        dest = (pulled_unit_path if pulled else unit_path)(
            dest_root, stage, str(entry["sha256"]) if pulled else key
        )
        if not dest.exists():
            _write_atomic(dest_root, dest, src.read_bytes())
