"""kill -9 at every commit step of a whole (toy) pipeline run: 0 corrupt artifacts.

A forked child runs the pipeline with `os.fsync`, `os.rename` and `os.replace` wrapped
so that it SIGKILLs itself just before, or just after, the n-th of those calls; n walks
every step of the run (file fsyncs, manifest fsync, directory fsyncs, the rename into
place, the run record and fingerprint-cache replaces). After each kill every visible
artifact must verify, nothing may look like a broken artifact, `gc` must heal the
leftovers, and a rerun must give byte-identical artifacts.
"""

from __future__ import annotations

import hashlib
import os
import signal
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from test_engine_cache import run_toy

from sonarmap.pipeline.engine.store.artifact_store import ArtifactRef, ArtifactStore


def _digests(store: Path) -> dict[str, str]:
    return {
        str(f.relative_to(store)): hashlib.sha256(f.read_bytes()).hexdigest()
        for f in sorted(store.glob("*/*/*"))
        if f.parent.parent.name != "runs" and not f.parent.parent.name.startswith(".")
        and f.name != "manifest.json"
    }  # fmt: skip


def _killed_run(data: Path, store: Path, n: int, when: str) -> bool:
    """Run the pipeline in a child killed at step n; False if it finished first."""
    pid = os.fork()
    if pid == 0:  # the child: never returns into pytest
        try:
            calls = 0

            def wrap(fn: Callable[..., Any]) -> Callable[..., Any]:
                def step(*args: Any, **kwargs: Any) -> Any:
                    nonlocal calls
                    calls += 1
                    if calls == n and when == "before":
                        os.kill(os.getpid(), signal.SIGKILL)
                    out = fn(*args, **kwargs)
                    if calls == n and when == "after":
                        os.kill(os.getpid(), signal.SIGKILL)
                    return out

                return step

            os.fsync, os.rename, os.replace = wrap(os.fsync), wrap(os.rename), wrap(os.replace)
            run_toy(data, store)
            os._exit(0)
        except BaseException:
            os._exit(3)
    _, status = os.waitpid(pid, 0)
    if os.WIFEXITED(status):
        assert os.WEXITSTATUS(status) == 0
        return False
    assert os.WTERMSIG(status) == signal.SIGKILL
    return True


def _assert_consistent(store_dir: Path, clean: dict[str, str]) -> None:
    store = ArtifactStore(store_dir)
    items = list(store.scan())
    assert all(isinstance(i, ArtifactRef) for i in items), [str(i) for i in items]
    for ref in items:
        assert isinstance(ref, ArtifactRef)
        store.verify(ref)
    visible = _digests(store_dir)
    assert all(clean[name] == digest for name, digest in visible.items())
    store.run_records()  # parseable, whatever the kill left


@pytest.mark.parametrize("when", ["before", "after"])
def test_sigkill_at_every_commit_step_never_corrupts(tmp_path: Path, when: str) -> None:
    data = tmp_path / "raw.bin"
    data.write_bytes(bytes(range(256)) * 4)
    run_toy(data, tmp_path / "clean")
    clean = _digests(tmp_path / "clean")
    steps = 0
    for n in range(1, 200):
        store_dir = tmp_path / f"{when}{n}"
        if not _killed_run(data, store_dir, n, when):
            break
        steps += 1
        _assert_consistent(store_dir, clean)
        ArtifactStore(store_dir).gc()
        assert not list((store_dir / ".tmp").glob("*")), n
        assert not list(store_dir.glob("runs/.*.tmp")) and not list(store_dir.glob(".cache/*.tmp*"))
        run_toy(data, store_dir)
        assert _digests(store_dir) == clean
    # 4 commits of >= 4 steps each, plus the run record and the fingerprint cache.
    assert steps >= 18, steps
