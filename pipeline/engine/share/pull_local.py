"""The local side of a `pull`: which artifacts the store must fetch, and the record that
keeps what was pulled.

- An artifact the store already holds whole is not fetched again. One it holds damaged
  (a file or work unit that no longer matches its manifest, a manifest naming another
  artifact) is fetched and replaces the local copy, with a line saying so: a pull that
  reported "0 artifacts" over a damaged copy left the damage in place.
- Files are fetched into the store's resume cache, named by their sha256, so an
  interrupted pull reuses what it already verified (`download_job`); a committed or
  refused artifact's files leave it (`forget_cached`).
- `gc` keeps what run records name, and a pull is no run: without a record of its own,
  the next `gc` removed everything it had just fetched. Each pull writes one
  (`runs/pull-<hash>.json`) naming the artifacts asked for; their upstream is kept
  through their manifests, as for a run.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import time
import uuid
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from sonarmap.pipeline.engine.errors import ArtifactCorrupt
from sonarmap.pipeline.engine.hashing import sha256_file
from sonarmap.pipeline.engine.share.transfer import Job, download
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
from sonarmap.pipeline.engine.store.disk import discard_artifact

__all__ = ["download_job", "forget_cached", "record_pull", "replace_damaged", "to_fetch"]

log = logging.getLogger(__name__)


def to_fetch(
    store: ArtifactStore, order: Sequence[tuple[str, str]]
) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
    """(the artifacts of `order` the store lacks or holds damaged, in `order`'s order;
    the damaged ones among them). A damaged copy stays until `replace_damaged`, once
    every file of the pull is verified: a pull that fails changes nothing locally."""
    fetch, damaged = [], []
    for stage, key in order:
        try:
            ref = store.get(stage, key)
            if ref is not None:
                store.verify(ref)
                continue
        except ArtifactCorrupt as err:
            log.warning(
                "%s/%s: the local copy is damaged (%s); fetching it again",
                stage,
                key[:12],
                str(err).split("; ", 1)[0],
            )
            damaged.append((stage, key))
        fetch.append((stage, key))
    return fetch, damaged


def replace_damaged(store: ArtifactStore, damaged: Sequence[tuple[str, str]]) -> None:
    """Move the damaged local copies out of sight, just before their fetched copies are
    committed in their place (a commit reuses whatever holds its key)."""
    for stage, key in damaged:
        discard_artifact(store, stage, key)


def record_pull(store: ArtifactStore, remote: str, wanted: Sequence[tuple[str, str]]) -> None:
    """Write the pull's record: the artifacts asked for, so `gc` keeps them (and what is
    upstream of them) until the record is deleted."""
    addresses = sorted({f"{stage}/{key}" for stage, key in wanted})
    if not addresses:
        return
    name = hashlib.sha256("\n".join([remote, *addresses]).encode()).hexdigest()[:20]
    store.record_run(
        f"pull-{name}",
        {
            "pulled_from": remote,
            "artifacts": addresses,
            "updated_at": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime())
            + f".{time.time_ns() % 10**9:09d}Z",
            "complete": True,
            "stages": {},
        },
    )


def forget_cached(cache: Path, manifests: Iterable[Mapping[str, Any]]) -> None:
    for manifest in manifests:
        for entry in manifest["files"].values():
            (cache / str(entry["sha256"])).unlink(missing_ok=True)


def download_job(
    fs: Any,
    src: str,
    dst: Path,
    entry: Mapping[str, Any],
    address: str,
    rel: str,
    cache: Path,
) -> Job:
    """Fetch one file into the store's resume cache (named by its sha256), then link it
    into the staging directory; a file an interrupted pull already verified is reused."""
    size, sha = int(entry["size"]), str(entry["sha256"])
    folder, _, name = address.rpartition("/")  # stage/key of an artifact, or a unit's path
    where = f"remote {folder[:60]}/{name[:12]}" + (f": file '{rel[:80]}'" if rel else "")
    cached = cache / sha

    def run(progress: Callable[[int], None]) -> bool:
        sent = not (
            cached.is_file() and cached.stat().st_size == size and sha256_file(cached) == sha
        )
        if sent:
            cache.mkdir(parents=True, exist_ok=True)
            part = cache / f".{sha[:16]}.{uuid.uuid4().hex[:8]}.part"
            try:
                download(fs, src, part, size, sha, where, progress)
                os.replace(part, cached)
            finally:
                part.unlink(missing_ok=True)
        else:
            progress(size)
        try:
            os.link(cached, dst)
        except OSError:
            shutil.copyfile(cached, dst)
        return sent

    return Job(run, size)
