"""Reading a remote: which complete artifacts it holds, and their manifests, checked.

Everything here runs before a byte of an artifact's files is fetched: listing keeps only
artifacts with a manifest (a push in progress is invisible) and skips the store's
reserved folders; a manifest is read with a size cap and refused unless its stage is
the path's and the recipe's, its key is its recipe's hash, every declared size is under
the cap, and a model's sha256 is pinned (`sonarmap.pipeline.engine.share.trust`).
"""

from __future__ import annotations

import json
import re
from typing import Any

from sonarmap.pipeline.engine.errors import ArtifactCorrupt, PipelineError, StoreError
from sonarmap.pipeline.engine.hashing import recipe_key
from sonarmap.pipeline.engine.share.remotes import open_remote
from sonarmap.pipeline.engine.share.transfer import max_file_bytes
from sonarmap.pipeline.engine.share.trust import TrustPolicy, check_not_reserved
from sonarmap.pipeline.engine.store.artifact import escapes
from sonarmap.pipeline.engine.store.manifest import parse_manifest
from sonarmap.pipeline.engine.text import one_line

__all__ = [
    "MAX_LISTED_OBJECTS",
    "MAX_LISTING",
    "MAX_MANIFEST_BYTES",
    "list_remote",
    "remote_manifest",
    "remote_stages",
    "resolve_remote",
]

MANIFEST = "manifest.json"
MAX_MANIFEST_BYTES = 16 << 20
_HEX = re.compile(r"^[0-9a-f]{1,64}$")


MAX_LISTING = 10_000
"""Most entries one remote folder may list where each entry then costs a request of its
own (sftp and http hold no recursive listing: one request per key to find its manifest,
so 10,000 keys are minutes, not hours); a longer listing is refused."""

MAX_LISTED_OBJECTS = 1_000_000
"""Most objects one paged object-store listing may walk (1,000 requests of 1,000; the keys
kept are ~120 MB at most): past it the listing is refused."""

_PAGE = 1000
"""Objects per listing request (S3's most)."""


def _names(fs: Any, path: str) -> list[str]:
    """Last path components under `path` (directories and files), [] when absent."""
    try:
        entries = fs.ls(path, detail=False)
    except FileNotFoundError:
        return []
    if len(entries) > MAX_LISTING:
        raise StoreError(
            f"remote folder {path.rsplit('/', 2)[-1][:60]!r} lists {len(entries)} entries, over "
            f"the limit of {MAX_LISTING}; pull by stage and key prefix from a smaller remote"
        )
    return sorted({str(p).rstrip("/").rsplit("/", 1)[-1] for p in entries})


def _protocol(fs: Any) -> str:
    return str(fs.protocol if isinstance(fs.protocol, str) else fs.protocol[0])


def _keys(fs: Any, root: str, stage: str) -> list[str]:
    """Keys of committed artifacts (with a manifest) of `stage` at the remote."""
    if _protocol(fs) in ("s3", "s3a"):
        return _s3_keys(fs, f"{root}/{stage}")
    return [
        k
        for k in _names(fs, f"{root}/{stage}")
        if _HEX.match(k) and fs.exists(f"{root}/{stage}/{k}/{MANIFEST}")
    ]


def _s3_keys(fs: Any, folder: str) -> list[str]:
    """Keys under `folder` holding a manifest, from one paged listing of every object
    below it (a request per 1,000 objects, where asking each key would be one per key)."""
    bucket, _, prefix = folder.partition("/")
    prefix = f"{prefix}/" if prefix else ""
    keys: list[str] = []
    seen = 0
    token: dict[str, str] = {}
    while True:
        try:
            page = fs.call_s3(
                "list_objects_v2", Bucket=bucket, Prefix=prefix, MaxKeys=_PAGE, **token
            )
        except FileNotFoundError:
            return []
        contents = page.get("Contents", [])
        seen += len(contents)
        if seen > MAX_LISTED_OBJECTS:
            raise StoreError(
                f"remote folder {folder.rsplit('/', 1)[-1][:60]!r} lists over "
                f"{MAX_LISTED_OBJECTS} objects; pull by stage and key prefix from a smaller "
                "remote"
            )
        for obj in contents:
            key, _, name = str(obj.get("Key", ""))[len(prefix) :].partition("/")
            if name == MANIFEST and _HEX.match(key):
                keys.append(key)
        if not page.get("IsTruncated") or not page.get("NextContinuationToken"):
            return sorted(keys)
        token = {"ContinuationToken": str(page["NextContinuationToken"])}


def remote_stages(fs: Any, root: str) -> list[str]:
    stages = []
    for name in _names(fs, root):
        try:
            check_not_reserved(name, "remote")
        except ArtifactCorrupt:
            continue
        stages.append(name)
    return stages


def list_remote(remote: str) -> list[str]:
    """ "stage/key" of every complete artifact (manifest present) at `remote`."""
    fs, root = open_remote(remote)
    return [f"{s}/{k}" for s in remote_stages(fs, root) for k in _keys(fs, root, s)]


def _read_capped(fs: Any, path: str, cap: int, where: str) -> bytes:
    """At most `cap` bytes of a regular file (a FIFO would block the open forever, a device
    would never end: neither is a manifest)."""
    kind = fs.info(path).get("type", "file")  # FileNotFoundError: the caller's to name
    if kind != "file":
        raise ArtifactCorrupt(f"{where}: manifest is not a regular file ({str(kind)[:20]})")
    with fs.open(path, "rb") as f:
        data: bytes = f.read(cap + 1)
    if len(data) > cap:
        raise ArtifactCorrupt(f"{where}: manifest is larger than {cap} bytes")
    return data


def remote_manifest(
    fs: Any, root: str, stage: str, key: str, policy: TrustPolicy
) -> dict[str, Any]:
    """The remote's manifest for `stage/key`, after every check that needs no file."""
    where = f"remote {stage[:40]}/{key[:12]}"
    check_not_reserved(stage, where)
    try:
        raw = _read_capped(fs, f"{root}/{stage}/{key}/{MANIFEST}", MAX_MANIFEST_BYTES, where)
    except FileNotFoundError as err:
        raise StoreError(f"remote has no artifact {stage}/{key[:12]}") from err
    try:
        manifest: Any = json.loads(raw)
    except (ValueError, RecursionError) as err:  # RecursionError: nesting bombs
        raise ArtifactCorrupt(f"{where}: manifest is not JSON") from err
    model = parse_manifest(manifest, where)
    if model.stage != stage or model.key != key:
        raise ArtifactCorrupt(f"{where}: manifest names another artifact")
    policy.check_files(stage, model.files, where)
    for rel in model.files:  # named as the remote's, before a local folder exists
        if escapes(rel):
            raise ArtifactCorrupt(
                f"{where}: manifest lists the file '{one_line(rel, 80)}', a path outside"
                " the artifact"
            )
    if model.recipe is None:
        # Without a recipe nothing ties the key to the content: refuse rather than trust.
        raise ArtifactCorrupt(f"{where}: manifest has no recipe, so its key cannot be checked")
    if model.recipe.get("stage") != stage:
        raise ArtifactCorrupt(
            f"{where}: recipe is for stage {str(model.recipe.get('stage'))[:40]!r}, not {stage!r}"
        )
    try:
        if recipe_key(model.recipe) != key:
            raise ArtifactCorrupt(f"{where}: key does not match the manifest's recipe")
    except ArtifactCorrupt:
        raise
    except PipelineError as err:
        raise ArtifactCorrupt(f"{where}: the manifest's recipe cannot be hashed") from err
    cap = max_file_bytes()
    for rel, entry in model.files.items():
        if entry.size > cap:
            raise ArtifactCorrupt(
                f"{where}: '{rel[:80]}' declares {entry.size} bytes, over the {cap}-byte limit "
                "(SONARMAP_MAX_FILE_BYTES)"
            )
    policy.check_model(stage, key, manifest, where)
    return dict(manifest)


def resolve_remote(fs: Any, root: str, target: str) -> list[tuple[str, str]]:
    if not _HEX.match(target):
        check_not_reserved(target, "pull")
    stages = remote_stages(fs, root)
    if target in stages:
        return [(target, k) for k in _keys(fs, root, target)]
    hits = [(s, k) for s in stages for k in _keys(fs, root, s) if k.startswith(target)]
    if len(hits) != 1:
        raise StoreError(f"remote: '{target[:40]}' matches {len(hits)} artifacts, expected 1")
    return hits
