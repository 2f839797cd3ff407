"""Inputs several QA cases share: a small simulated recording, made once and copied."""

from __future__ import annotations

import shutil
from pathlib import Path

from pipeline.training.datasets import Simulation, ensure_simulations, scene_path

ROOT = Path(__file__).resolve().parents[2]
CACHE = ROOT / "data" / "qa"


def small_recording(dest: Path, seed: int = 1, duration_s: float = 20.0) -> Path:
    """A copy of the tiny scene's mission (simulated once into `data/qa/`) at `dest`."""
    out = CACHE / f"tiny-seed{seed}-{duration_s:g}s.mcap"
    ensure_simulations([Simulation(scene_path("tiny"), seed, out, duration_s=duration_s)], 1)
    dest.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(out, dest)
    return dest
