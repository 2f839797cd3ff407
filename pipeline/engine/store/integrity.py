"""Integrity checks: a file or artifact directory against its manifest.

Used when the engine binds an artifact's file to a stage input (`verify_file`), by
`show --verify`, `push`, `pull` and `gc --broken` (`verify_artifact_dir`), and by
`status` on its hits (`size_damage`: sizes only). Every
message is one line naming the artifact and saying how to recover.
"""

from __future__ import annotations

import json
import stat
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from sonarmap.pipeline.engine.errors import ArtifactCorrupt, PipelineError, StoreError
from sonarmap.pipeline.engine.hashing import recipe_key, sha256_file
from sonarmap.pipeline.engine.store.artifact import ArtifactRef, safe_relative
from sonarmap.pipeline.engine.store.manifest import parse_manifest

__all__ = [
    "check_parses",
    "check_required_files",
    "recovery_hint",
    "size_damage",
    "verify_artifact_dir",
    "verify_file",
]

_MANIFEST = "manifest.json"


def check_required_files(
    stage: str, files: Iterable[str], required: Mapping[str, frozenset[str]], where: str
) -> None:
    """Refuse a manifest that lacks a file every artifact of `stage` holds (`required`:
    stage -> such files): every file it lists can match, and the next stage still fails.

    Raises:
        ArtifactCorrupt: naming the first missing file.
    """
    missing = sorted(required.get(stage, frozenset()) - set(files))
    if missing:
        raise ArtifactCorrupt(
            f"{where}: manifest lists no '{missing[0][:80]}', which every {stage} artifact holds"
        )


def recovery_hint(stage: str) -> str:
    """How a user gets rid of a corrupt artifact (appended to every corruption error)."""
    return f"remove it with `sonarmap gc --broken`, or recompute it with `--force {stage}`"


def verify_file(ref: ArtifactRef, name: str) -> Path:
    """The path of one file after checking its size and sha256 against the manifest.

    The engine calls this for every file it binds to a stage input, so a flipped
    byte is refused before anything is computed from it (and committed under a
    key that claims clean inputs).
    """
    where = f"artifact {ref.stage}/{ref.key[:12]}: '{name}'"
    try:
        path = ref.file(name)
    except StoreError as err:  # a link leading out of the artifact, a name not listed
        raise ArtifactCorrupt(f"{where}: {err}; {recovery_hint(ref.stage)}") from err
    entry = ref.manifest["files"][name]
    try:
        size = path.stat().st_size
        digest = sha256_file(path) if size == int(entry["size"]) else ""
    except OSError as err:
        raise ArtifactCorrupt(
            f"{where} unreadable ({err.strerror}); {recovery_hint(ref.stage)}"
        ) from err
    if size != int(entry["size"]):
        raise ArtifactCorrupt(
            f"{where} has {size} bytes, its manifest says {entry['size']}; "
            f"{recovery_hint(ref.stage)}"
        )
    if digest != entry["sha256"]:
        raise ArtifactCorrupt(
            f"{where} does not match its manifest's sha256 (the file was altered); "
            f"{recovery_hint(ref.stage)}"
        )
    return path


def size_damage(ref: ArtifactRef) -> str | None:
    """What a look at the file sizes finds wrong with an artifact (a file missing, not a
    plain file, or of another size than its manifest's), None when they all match. A
    stat per file, no hashing: a changed byte needs `verify_file`."""
    for name, entry in ref.manifest.get("files", {}).items():
        where = f"artifact {ref.stage}/{ref.key[:12]}: '{name}'"
        try:
            path = ref.file(name)
            st = path.lstat()
        except StoreError as err:
            return f"{where}: {err}"
        except FileNotFoundError:
            return f"{where} is missing"
        except OSError as err:
            return f"{where} unreadable ({err.strerror})"
        if not stat.S_ISREG(st.st_mode):
            return f"{where} is not a plain file"
        if st.st_size != int(entry["size"]):
            return f"{where} has {st.st_size} bytes, its manifest says {entry['size']}"
    return None


def verify_artifact_dir(path: Path, manifest: Mapping[str, Any]) -> None:
    """Raise `ArtifactCorrupt` unless every listed file matches and the key matches the recipe."""
    model = parse_manifest(dict(manifest), str(path / _MANIFEST))
    if model.recipe is not None:
        try:
            key = recipe_key(model.recipe)
        except PipelineError as err:
            raise ArtifactCorrupt(
                f"{path}: the manifest's recipe cannot be hashed ({err})"
            ) from err
        if key != model.key:
            raise ArtifactCorrupt(f"{path}: key does not match the manifest's recipe")
    for rel, info in manifest["files"].items():
        f = safe_relative(path, rel)
        if not f.is_file():
            raise ArtifactCorrupt(f"{path}: missing file '{rel}'")
        if f.stat().st_size != int(info["size"]):
            raise ArtifactCorrupt(
                f"{path}: '{rel}' has size {f.stat().st_size}, expected {info['size']}"
            )
        if sha256_file(f) != info["sha256"]:
            raise ArtifactCorrupt(f"{path}: '{rel}' sha256 does not match its manifest")


_MAGIC = {
    ".mcap": (b"\x89MCAP0\r\n", b"\x89MCAP0\r\n"),
    ".pt": (b"PK\x03\x04", b""),
    ".png": (b"\x89PNG\r\n\x1a\n", b""),
}


def check_parses(path: Path, where: str) -> None:
    """Refuse a file that does not parse as the kind its name declares.

    A manifest's sha256 only proves the file is the one the manifest's author listed;
    a remote can list junk. Parquet footers are opened (cheap: metadata only), JSON is
    decoded, MCAP, torch and PNG files must carry their format's magic bytes.
    """
    suffix = path.suffix.lower()
    try:
        if suffix == ".parquet":
            import pyarrow.parquet as pq

            pq.read_metadata(path)
        elif suffix == ".json":
            json.loads(path.read_bytes())
        elif suffix in _MAGIC:
            head, tail = _MAGIC[suffix]
            with path.open("rb") as f:
                ok = f.read(len(head)) == head
                if ok and tail:
                    f.seek(-len(tail), 2)
                    ok = f.read(len(tail)) == tail
            if not ok:
                raise ValueError(f"no {suffix[1:]} magic bytes")
    except (OSError, ValueError) as err:  # pyarrow's ArrowInvalid is a ValueError
        reason = (str(err).splitlines() or [type(err).__name__])[0]
        raise ArtifactCorrupt(
            f"{where}: '{path.name}' does not parse as {suffix[1:]} ({reason})"
        ) from err
