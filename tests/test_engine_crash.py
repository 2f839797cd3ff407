"""Crash safety and concurrency of the artifact store, with real processes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore

TESTS = Path(__file__).resolve().parent

SLOW_COMMIT = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore

    store = ArtifactStore(Path(sys.argv[1]))

    def build(tmp):
        for i in range(40):
            (tmp / f"part{i:02d}.bin").write_bytes(bytes([i]) * 200_000)
            time.sleep(0.02)
        return {"parts": 40}

    print("start", flush=True)
    store.commit("slow", "ab" * 32, build, {"recipe": None})
    print("done", flush=True)
    """
)

RUN_TOY = textwrap.dedent(
    """
    import sys
    from pathlib import Path
    from toy_stages import TOY_STAGES
    from sonarmap.pipeline.engine.run.runner import execute, plan
    from sonarmap.pipeline.engine.run.session import make_context

    data, store = Path(sys.argv[1]), Path(sys.argv[2])
    ctx = make_context(data, stages=TOY_STAGES, overrides=["double.sleep_s=1.0"], store_dir=store,
                       parts=lambda p: [p], opener=lambda _s: data.read_bytes())
    result = execute(plan(ctx.stages, ctx.config, ctx.dataset, ctx.store), ctx.config, ctx.dataset, ctx.store)
    print([r.key for r in result.stages])
    """
)


def _env(tmp_path: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(TESTS), str(TESTS.parent)])
    env["TOY_CALL_LOG"] = str(tmp_path / "calls.log")
    return env


def test_sigkill_during_commit_leaves_no_visible_or_corrupt_artifact(tmp_path: Path) -> None:
    store_dir = tmp_path / "store"
    script = tmp_path / "slow_commit.py"
    script.write_text(SLOW_COMMIT)
    visible = []
    for delay in (0.05, 0.3, 0.6, 0.8, 0.85, 0.9):
        proc = subprocess.Popen(
            [sys.executable, str(script), str(store_dir)],
            stdout=subprocess.PIPE,
            env=_env(tmp_path),
        )
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == b"start"
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        store = ArtifactStore(store_dir)
        ref = store.get("slow", "ab" * 32)
        if ref is not None:  # killed after the rename: it must then be complete
            store.verify(ref)
            assert len(ref.manifest["files"]) == 40
            visible.append(delay)
            break
    assert 0.05 not in visible and 0.3 not in visible and 0.6 not in visible
    # A later commit works and is complete; the stale temporaries are collected.
    done = subprocess.run(
        [sys.executable, str(script), str(store_dir)], env=_env(tmp_path), capture_output=True
    )
    assert done.returncode == 0, done.stderr
    store = ArtifactStore(store_dir)
    ref = store.get("slow", "ab" * 32)
    assert ref is not None and len(ref.manifest["files"]) == 40
    store.verify(ref)
    report = store.gc(stale_tmp_s=0.0, dry_run=True)
    assert report["tmp_removed"] >= 1


def test_two_processes_same_key_exactly_one_computes(tmp_path: Path) -> None:
    data = tmp_path / "raw.bin"
    data.write_bytes(bytes(range(256)) * 4)
    store_dir = tmp_path / "store"
    script = tmp_path / "run_toy.py"
    script.write_text(RUN_TOY)
    procs = [
        subprocess.Popen(
            [sys.executable, str(script), str(data), str(store_dir)],
            env=_env(tmp_path),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        for _ in range(2)
    ]
    outs = [p.communicate(timeout=120) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1][-500:] for o in outs]
    assert outs[0][0] == outs[1][0]
    calls = (tmp_path / "calls.log").read_text().split("\n")
    names = [c.split()[0] for c in calls if c]
    assert names.count("double") == 1
    assert names.count("source") == 1
