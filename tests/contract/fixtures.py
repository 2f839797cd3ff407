"""Inputs several QA cases share: a small simulated recording, made once and copied."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from sonarmap.pipeline.training.datasets import Simulation, ensure_simulations, scene_path

ROOT = Path(__file__).resolve().parents[2]
CACHE = ROOT / "data" / "qa"


def small_recording(dest: Path, seed: int = 1, duration_s: float = 20.0) -> Path:
    """A copy of the tiny scene's mission (simulated once into `data/qa/`) at `dest`."""
    out = CACHE / f"tiny-seed{seed}-{duration_s:g}s.mcap"
    ensure_simulations([Simulation(scene_path("tiny"), seed, out, duration_s=duration_s)], 1)
    dest.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(out, dest)
    return dest


CODE = ("pipeline", "stages", "schemas", "sim", "configs")
"""What a cached run's artifacts depend on: another version of these makes other keys."""


def code_stamp() -> str:
    """A hash of the project's code and configs as they are on disk (tracked or not)."""
    digest = hashlib.sha256()
    for top in CODE:
        for path in sorted((ROOT / top).rglob("*")):
            if path.is_file() and "__pycache__" not in path.parts:
                digest.update(str(path.relative_to(ROOT)).encode())
                digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def sonarmap(work: Path, *args: str) -> None:
    """`sonarmap ARGS` in `work` with this checkout's code (raises on a non-zero exit)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    subprocess.run(
        [sys.executable, "-m", "sonarmap.pipeline", *args],
        cwd=work,
        env=env,
        check=True,
        capture_output=True,
    )


def cached_run(name: str, extra: Sequence[Sequence[str]] = ()) -> Path:
    """A work dir after `sonarmap run rec.mcap` on a recording with a map, then the
    `extra` commands, made once per version of the code into `data/qa/<name>/`."""
    run = CACHE / name
    stamp = run / "code-stamp"
    now = code_stamp()
    if not stamp.is_file() or stamp.read_text() != now:
        shutil.rmtree(run, ignore_errors=True)
        run.mkdir(parents=True)
        small_recording(run / "rec.mcap", seed=2, duration_s=45.0)
        for args in (["run", "rec.mcap", "-q"], *extra):
            sonarmap(run, *args)
        stamp.write_text(now)
    return run
