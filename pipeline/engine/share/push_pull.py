"""Sharing artifacts: push to and pull from any fsspec URL, verified on the way in.

A remote mirrors the store layout (`<remote>/<stage>/<key>/manifest.json` + files), and
an artifact exists there once its manifest does: push sends every file first and each
manifest last (renamed into place where the filesystem can, one atomic PUT on S3), so
a reader never sees a partial artifact and a directory without a manifest is ignored.
A file already at the remote with the right size and sha256 is not sent again, which
makes an interrupted push resumable.

Pull trusts nothing the remote says until it has checked it (`sonarmap.pipeline.engine.share.trust`):
the stage is not a reserved store folder and equals the recipe's and the path's, the key
is the hash of the recipe, a model's file sha256 is pinned, every file is streamed with
its declared size as a hard limit and hashed on the way, parses as the kind its name
says (`model.pt` is loaded weights-only), and only then is anything committed (and
recorded: `pull_local`). Manifests are JSON; nothing is ever unpickled. Work units travel
with their artifact (`unit_share`).
"""

from __future__ import annotations

import errno
import logging
import re
import shutil
import uuid
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from sonarmap.pipeline.engine.errors import ArtifactCorrupt, StoreError
from sonarmap.pipeline.engine.share.pull_local import (
    download_job,
    forget_cached,
    record_pull,
    replace_damaged,
    to_fetch,
)
from sonarmap.pipeline.engine.share.remote_index import (
    list_remote,
    remote_manifest,
    remote_stages,
    resolve_remote,
)
from sonarmap.pipeline.engine.share.remotes import (
    check_bucket,
    deadline,
    display,
    open_remote,
    read_only,
    remote_failure,
)
from sonarmap.pipeline.engine.share.transfer import (
    Job,
    TransferStats,
    os_error,
    run_jobs,
    upload,
)
from sonarmap.pipeline.engine.share.trust import MODEL_FILE, TrustPolicy, check_model_file
from sonarmap.pipeline.engine.share.unit_share import install_units, staged_units, unit_files
from sonarmap.pipeline.engine.store.artifact import PULL_CACHE
from sonarmap.pipeline.engine.store.artifact_store import (
    MANIFEST,
    ArtifactRef,
    ArtifactStore,
    safe_relative,
)
from sonarmap.pipeline.engine.store.disk import free_bytes
from sonarmap.pipeline.engine.store.integrity import check_parses
from sonarmap.pipeline.engine.store.manifest import ADDRESS_PATTERN
from sonarmap.pipeline.engine.store.units import unit_entries

__all__ = ["list_remote", "pull", "push"]

log = logging.getLogger(__name__)
"""Verified files of an unfinished pull, by sha256, so the next pull does not fetch them again."""

Leaf = Callable[[str, str, Mapping[str, Any]], bool]


def _upstream_closure(
    refs: Iterable[tuple[str, str]],
    manifest_of: Callable[[str, str], Mapping[str, Any]],
    with_upstream: bool,
    is_leaf: Leaf = lambda s, k, m: False,
) -> list[tuple[str, str]]:
    """(stage, key) pairs with every upstream artifact, upstream first; a leaf (a shipped
    model, whose provenance is its lock) is taken without its upstream."""
    order: list[tuple[str, str]] = []
    seen: set[tuple[str, str]] = set()

    def visit(stage: str, key: str) -> None:
        if (stage, key) in seen:
            return
        seen.add((stage, key))
        manifest = manifest_of(stage, key)
        if with_upstream and not is_leaf(stage, key, manifest):
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
                        f"{stage}/{key[:12]}: upstream address {str(address)[:80]!r} is not "
                        "<stage>/<key>"
                    )
                up_stage, _, up_key = address.partition("/")
                visit(up_stage, up_key)
        order.append((stage, key))

    for stage, key in refs:
        visit(stage, key)
    return order


def _write_manifest(fs: Any, dest: str, data: bytes) -> None:
    """Make the artifact at `dest` visible: one atomic PUT on object stores, else a
    temporary name renamed into place (a reader never reads half a manifest)."""
    protocol = fs.protocol if isinstance(fs.protocol, str) else fs.protocol[0]
    if protocol in ("s3", "s3a", "gs", "gcs"):
        fs.pipe_file(f"{dest}/{MANIFEST}", data, **deadline(fs, len(data)))
        return
    tmp = f"{dest}/.{MANIFEST}.{uuid.uuid4().hex[:12]}.tmp"
    fs.pipe_file(tmp, data, **deadline(fs, len(data)))
    try:
        fs.mv(tmp, f"{dest}/{MANIFEST}")
    except OSError:
        # SFTP's rename refuses an existing target: another push committed it first.
        if not fs.exists(f"{dest}/{MANIFEST}"):
            raise
        fs.rm(tmp)


def push(
    store: ArtifactStore,
    remote: str,
    targets: Sequence[str] = (),
    *,
    with_upstream: bool = True,
    fallbacks: Sequence[ArtifactStore] = (),
    policy: TrustPolicy | None = None,
    stats: TransferStats | None = None,
    create: bool = False,
) -> list[str]:
    """Copy artifacts (by stage name or key prefix; all when none given) to `remote`.

    Upstream artifacts missing from `store` are taken from `fallbacks` (the model cache
    holds the training datasets a store's model was trained on); a shipped model
    (`policy.leaves`) is pushed without its training data. Returns the "stage/key"
    addresses now at the remote.

    Raises:
        StoreError: an upstream artifact is missing everywhere (named), the remote is
            read-only, full or unwritable (named, exit 2).
    """
    policy = policy or TrustPolicy()
    stats = stats if stats is not None else TransferStats()
    if read_only(remote):
        raise StoreError(
            f"remote {display(remote)} is read-only (http); push to a path, s3:// or sftp://"
        )
    fs, root = open_remote(remote)
    try:
        check_bucket(fs, root, remote, create)
        if not store.root.is_dir():  # a mistyped --store pushed nothing, exit 0
            raise StoreError(f"{store.root}: no store there (check --store)")
        return _push(store, fs, root, remote, targets, with_upstream, fallbacks, policy, stats)
    except (StoreError, ArtifactCorrupt):
        raise
    except Exception as err:  # a library's own error types: named with their cause
        raise remote_failure(err, remote, "push") from err


def _push(
    store: ArtifactStore,
    fs: Any,
    root: str,
    remote: str,
    targets: Sequence[str],
    with_upstream: bool,
    fallbacks: Sequence[ArtifactStore],
    policy: TrustPolicy,
    stats: TransferStats,
) -> list[str]:
    chosen = [store.find(t) for t in targets] if targets else list(store.iter_artifacts())

    def holder(stage: str, key: str) -> ArtifactRef:
        for source in (store, *fallbacks):
            ref = source.get(stage, key)
            if ref is not None:
                return ref
        raise StoreError(f"{stage}/{key[:12]}: upstream artifact missing from {store.root}")

    order = _upstream_closure(
        ((r.stage, r.key) for r in chosen),
        lambda s, k: holder(s, k).manifest,
        with_upstream,
        policy.is_leaf,
    )
    pending: list[ArtifactRef] = []
    for stage, key in order:
        ref = holder(stage, key)
        store.verify(ref)
        if not _exists(fs, f"{root}/{stage}/{key}/{MANIFEST}", remote):
            pending.append(ref)
    jobs = []
    for ref in pending:
        dest = f"{root}/{ref.stage}/{ref.key}"
        for rel, entry in sorted(ref.manifest["files"].items()):
            label = f"{display(remote)}/{ref.stage}/{ref.key[:12]}/{rel}"
            jobs.append(_upload_job(fs, ref.file(rel), f"{dest}/{rel}", entry, label))
        for src, rel, entry in unit_files(ref):  # its work units, before its manifest
            jobs.append(_upload_job(fs, src, f"{root}/{rel}", entry, f"{display(remote)}/{rel}"))
    run_jobs(jobs, f"push {display(remote)}", stats)
    for ref in pending:  # upstream first: a visible artifact's inputs are visible too
        dest = f"{root}/{ref.stage}/{ref.key}"
        try:
            _write_manifest(fs, dest, (ref.path / MANIFEST).read_bytes())
        except OSError as err:
            raise os_error(err, f"{display(remote)}/{ref.stage}/{ref.key[:12]}") from err
    log.info("pushed %d artifacts to %s (%d files sent)", len(order), display(remote), stats.sent)
    return [f"{s}/{k}" for s, k in order]


def _exists(fs: Any, path: str, remote: str) -> bool:
    try:
        return bool(fs.exists(path, **deadline(fs)))
    except TimeoutError:
        raise  # the remote's (an OSError too), named by `push` with its cause
    except OSError as err:
        raise os_error(err, display(remote)) from err


def _upload_job(fs: Any, src: Path, dst: str, entry: Mapping[str, Any], label: str) -> Job:
    size, sha = int(entry["size"]), str(entry["sha256"])

    def run(progress: Callable[[int], None]) -> bool:
        try:
            return upload(fs, src, dst, size, sha, progress)
        except TimeoutError:
            raise  # the remote's deadline (an OSError too), named by `push` with its cause
        except OSError as err:
            raise os_error(err, label) from err

    return Job(run, size)


def pull(
    store: ArtifactStore,
    remote: str,
    targets: Sequence[str] = (),
    *,
    with_upstream: bool = True,
    policy: TrustPolicy | None = None,
    stats: TransferStats | None = None,
) -> list[ArtifactRef]:
    """Download, verify and commit artifacts from `remote` (all-or-nothing).

    Raises:
        ArtifactCorrupt: a reserved stage, a key that does not match its recipe, an
            unpinned model, a path escaping the artifact directory, a missing, oversized,
            truncated or altered file, a file that does not parse.
        StoreError: the store's disk is full or read-only (named).
    """
    policy = policy or TrustPolicy()
    stats = stats if stats is not None else TransferStats()
    fs, root = open_remote(remote)
    try:
        return _pull(store, fs, root, remote, targets, with_upstream, policy, stats)
    except (StoreError, ArtifactCorrupt):
        raise
    except OSError as err:
        # A full or read-only disk is the store's; anything else without a local file
        # name (refused connection, timeout, permission at the server) is the remote's.
        local = isinstance(err.filename, str) and err.filename.startswith(str(store.root))
        if local or err.errno in (errno.ENOSPC, errno.EROFS, errno.EDQUOT):
            where = err.filename if local else str(store.root)
        else:
            raise remote_failure(err, remote, "pull") from err
        raise os_error(err, where) from err
    except Exception as err:  # a library's own error types: named with their cause
        raise remote_failure(err, remote, "pull") from err


def _pull(
    store: ArtifactStore,
    fs: Any,
    root: str,
    remote: str,
    targets: Sequence[str],
    with_upstream: bool,
    policy: TrustPolicy,
    stats: TransferStats,
) -> list[ArtifactRef]:
    if not read_only(remote) and not fs.exists(root):
        raise StoreError(f"remote {display(remote)} does not exist")
    if not read_only(remote) and fs.isfile(root):
        raise StoreError(f"remote {display(remote)} is a file, not a folder of artifacts")
    stages = list(targets) or remote_stages(fs, root)
    if not stages and read_only(remote):
        # A web server without directory listings looks empty.
        raise StoreError(
            f"remote {display(remote)} lists no stage folders (is directory listing enabled?)"
        )
    wanted: list[tuple[str, str]] = []
    for t in stages:
        wanted.extend(resolve_remote(fs, root, t))
    manifests: dict[tuple[str, str], dict[str, Any]] = {}

    def manifest_of(stage: str, key: str) -> dict[str, Any]:
        if (stage, key) not in manifests:
            manifests[(stage, key)] = remote_manifest(fs, root, stage, key, policy)
        return manifests[(stage, key)]

    order = _upstream_closure(wanted, manifest_of, with_upstream, policy.is_leaf)
    missing, damaged = to_fetch(store, order)
    units = {(s, k): unit_entries(manifest_of(s, k), f"remote {s}/{k[:12]}") for s, k in missing}
    need = sum(int(e["size"]) for s, k in missing for e in manifest_of(s, k)["files"].values())
    need += sum(int(e["size"]) for listed in units.values() for e in listed.values())
    free = free_bytes(store.root)
    if need > free:
        raise StoreError(f"{store.root}: pull needs {need} bytes, the disk has {free} free")
    staging = store.tmp_path("pull")
    cache = store.root / PULL_CACHE
    try:
        jobs = []
        for stage, key in missing:
            local = staging / stage / key
            local.mkdir(parents=True)
            for rel, entry in manifest_of(stage, key)["files"].items():
                dst = safe_relative(local, rel)
                dst.parent.mkdir(parents=True, exist_ok=True)
                jobs.append(
                    download_job(
                        fs, f"{root}/{stage}/{key}/{rel}", dst, entry, f"{stage}/{key}", rel, cache
                    )
                )
            for rel, dst, entry in staged_units(staging, stage, units[(stage, key)]):
                jobs.append(download_job(fs, f"{root}/{rel}", dst, entry, rel, "", cache))
        run_jobs(jobs, f"pull {display(remote)}", stats)
        for stage, key in missing:
            # Sizes and sha256s were checked while streaming, the key before any download.
            local, manifest = staging / stage / key, manifest_of(stage, key)
            where = f"remote {stage}/{key[:12]}"
            for rel in manifest["files"]:
                path = safe_relative(local, rel)
                check_parses(path, where)
                if path.suffix == ".pt" or rel == MODEL_FILE:
                    check_model_file(path, where)
        install_units(store.root, staging, units)  # before the artifacts listing them
        replace_damaged(store, damaged)
        refs = [store.import_dir(staging / s / k, manifest_of(s, k)) for s, k in missing]
        forget_cached(cache, [manifest_of(s, k) for s, k in missing])  # committed: not needed
    except ArtifactCorrupt:
        # A refused file is not worth resuming (it would be refused again).
        forget_cached(cache, [manifest_of(s, k) for s, k in missing])
        raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    record_pull(store, display(remote), wanted)
    log.info("pulled %d artifacts from %s", len(refs), display(remote))
    return refs
