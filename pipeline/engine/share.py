"""Sharing artifacts: push to and pull from any fsspec URL, verified on the way in.

A remote mirrors the store layout (`<remote>/<stage>/<key>/manifest.json` + files).
Pulling downloads into a temporary directory inside the local store, checks that the
key matches the manifest's recipe, that no path escapes the artifact directory, and
every file's size and sha256; only when every requested artifact passes are they
committed (atomically, one by one), so a tampered or truncated transfer leaves the
local store unchanged. Manifests are JSON; nothing is ever unpickled.
"""

from __future__ import annotations

import json
import logging
import re
import shutil
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from pipeline.engine.errors import ArtifactCorrupt, StoreError
from pipeline.engine.integrity import check_parses
from pipeline.engine.manifest import ADDRESS_PATTERN, parse_manifest
from pipeline.engine.store import (
    MANIFEST,
    ArtifactRef,
    ArtifactStore,
    safe_relative,
    verify_artifact_dir,
)

__all__ = ["pull", "push"]

log = logging.getLogger(__name__)


def _fs(remote: str) -> tuple[Any, str]:
    import fsspec

    try:
        fs, root = fsspec.core.url_to_fs(remote)
    except (ImportError, ValueError) as err:
        raise StoreError(f"remote {remote}: {err}") from err
    return fs, root.rstrip("/")


def _upstream_closure(
    refs: Iterable[tuple[str, str]], manifest_of: Any, with_upstream: bool
) -> list[tuple[str, str]]:
    """(stage, key) pairs with every upstream artifact, upstream first."""
    order: list[tuple[str, str]] = []
    seen: set[tuple[str, str]] = set()

    def visit(stage: str, key: str) -> None:
        if (stage, key) in seen:
            return
        seen.add((stage, key))
        manifest = manifest_of(stage, key)
        if with_upstream:
            # `input_artifacts` names the producing stage ("keyframes/<key>") even when the
            # input is bound under another name (training reads several datasets).
            addresses = manifest.get("input_artifacts") or {
                name: f"{name.split('.', 1)[0]}/{k}"
                for name, k in manifest.get("inputs", {}).items()
            }
            for address in sorted(set(addresses.values())):
                # Checked before any I/O: "../x" would read outside the store or remote.
                if not isinstance(address, str) or not re.fullmatch(ADDRESS_PATTERN, address):
                    raise ArtifactCorrupt(
                        f"{stage}/{key[:12]}: upstream address {address!r} is not <stage>/<key>"
                    )
                up_stage, _, up_key = address.partition("/")
                visit(up_stage, up_key)
        order.append((stage, key))

    for stage, key in refs:
        visit(stage, key)
    return order


def push(
    store: ArtifactStore,
    remote: str,
    targets: Sequence[str] = (),
    *,
    with_upstream: bool = True,
    fallbacks: Sequence[ArtifactStore] = (),
) -> list[str]:
    """Copy artifacts (by stage name or key prefix; all when none given) to `remote`.

    Files go first and the manifest last, so a reader never sees a partial artifact.
    Upstream artifacts missing from `store` are taken from `fallbacks` (the model cache
    holds the training datasets a store's model was trained on). Returns the
    "stage/key" addresses pushed.
    """
    fs, root = _fs(remote)
    chosen = [store.find(t) for t in targets] if targets else list(store.iter_artifacts())

    def holder(stage: str, key: str) -> ArtifactRef:
        for source in (store, *fallbacks):
            ref = source.get(stage, key)
            if ref is not None:
                return ref
        raise StoreError(f"{stage}/{key[:12]}: upstream artifact missing from {store.root}")

    pushed = []
    for stage, key in _upstream_closure(
        ((r.stage, r.key) for r in chosen), lambda s, k: holder(s, k).manifest, with_upstream
    ):
        ref = holder(stage, key)
        store.verify(ref)
        dest = f"{root}/{stage}/{key}"
        if fs.exists(f"{dest}/{MANIFEST}"):
            pushed.append(f"{stage}/{key}")
            continue
        for rel in ref.manifest["files"]:
            fs.makedirs(f"{dest}/{Path(rel).parent.as_posix()}".rstrip("/."), exist_ok=True)
            fs.put_file(str(ref.file(rel)), f"{dest}/{rel}")
        fs.pipe_file(f"{dest}/{MANIFEST}", (ref.path / MANIFEST).read_bytes())
        pushed.append(f"{stage}/{key}")
    return pushed


def _remote_manifest(fs: Any, root: str, stage: str, key: str) -> dict[str, Any]:
    where = f"remote {stage}/{key[:12]}"
    try:
        manifest: Any = json.loads(fs.cat_file(f"{root}/{stage}/{key}/{MANIFEST}"))
    except FileNotFoundError as err:
        raise StoreError(f"remote has no artifact {stage}/{key[:12]}") from err
    except ValueError as err:
        raise ArtifactCorrupt(f"{where}: manifest is not JSON") from err
    model = parse_manifest(manifest, where)
    if model.stage != stage or model.key != key:
        raise ArtifactCorrupt(f"{where}: manifest names another artifact")
    if model.recipe is None:
        # Without a recipe nothing ties the key to the content: refuse rather than trust.
        raise ArtifactCorrupt(f"{where}: manifest has no recipe, so its key cannot be checked")
    return dict(manifest)


def _resolve_remote(fs: Any, root: str, target: str) -> list[tuple[str, str]]:
    stages = [p.rsplit("/", 1)[-1] for p in fs.ls(root, detail=False) if fs.isdir(p)]
    if target in stages:
        return [
            (target, p.rsplit("/", 1)[-1]) for p in sorted(fs.ls(f"{root}/{target}", detail=False))
        ]
    hits = [
        (s, p.rsplit("/", 1)[-1])
        for s in stages
        for p in fs.ls(f"{root}/{s}", detail=False)
        if p.rsplit("/", 1)[-1].startswith(target)
    ]
    if len(hits) != 1:
        raise StoreError(f"remote: '{target}' matches {len(hits)} artifacts, expected 1")
    return hits


def pull(
    store: ArtifactStore, remote: str, targets: Sequence[str] = (), *, with_upstream: bool = True
) -> list[ArtifactRef]:
    """Download, verify and commit artifacts from `remote` (all-or-nothing).

    Raises:
        ArtifactCorrupt: a key that does not match its recipe, a path escaping the
            artifact directory, a missing, truncated or altered file.
    """
    fs, root = _fs(remote)
    if not fs.exists(root):
        raise StoreError(f"remote {remote} does not exist")
    wanted: list[tuple[str, str]] = []
    if targets:
        for t in targets:
            wanted.extend(_resolve_remote(fs, root, t))
    else:
        for s in fs.ls(root, detail=False):
            wanted.extend(_resolve_remote(fs, root, s.rsplit("/", 1)[-1]))
    manifests: dict[tuple[str, str], dict[str, Any]] = {}

    def manifest_of(stage: str, key: str) -> dict[str, Any]:
        if (stage, key) not in manifests:
            manifests[(stage, key)] = _remote_manifest(fs, root, stage, key)
        return manifests[(stage, key)]

    order = _upstream_closure(wanted, manifest_of, with_upstream)
    staging = store.tmp_path("pull")
    try:
        staged = []
        for stage, key in order:
            if store.get(stage, key) is not None:
                continue
            manifest = manifest_of(stage, key)
            local = staging / stage / key
            local.mkdir(parents=True)
            for rel in manifest.get("files", {}):
                dst = safe_relative(local, rel)
                dst.parent.mkdir(parents=True, exist_ok=True)
                try:
                    fs.get_file(f"{root}/{stage}/{key}/{rel}", str(dst))
                except FileNotFoundError as err:
                    raise ArtifactCorrupt(
                        f"remote {stage}/{key[:12]}: file '{rel}' missing"
                    ) from err
            verify_artifact_dir(local, manifest)
            for rel in manifest["files"]:
                check_parses(safe_relative(local, rel), f"remote {stage}/{key[:12]}")
            staged.append((local, manifest))
        refs = [store.import_dir(local, manifest) for local, manifest in staged]
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    log.info("pulled %d artifacts from %s", len(refs), remote)
    return refs
