"""Simulations on demand (`sonarmap.pipeline.training.datasets`): the demo simulates the mapped
scene and the training scenes concurrently (issue 22); the files must be the ones a
one-after-the-other run writes, and a current file is never simulated again."""

from __future__ import annotations

from pathlib import Path

from sonarmap.pipeline.training.datasets import Simulation, ensure_simulations, scene_path


def _sims(folder: Path) -> list[Simulation]:
    tiny = scene_path("tiny")
    return [
        Simulation(tiny, seed, folder / f"tiny-seed{seed}.mcap", duration_s=4) for seed in (3, 4)
    ]


def test_concurrent_simulations_write_what_one_after_the_other_writes(tmp_path: Path) -> None:
    together = ensure_simulations(_sims(tmp_path / "together"), workers=2)
    alone = ensure_simulations(_sims(tmp_path / "alone"), workers=1)
    assert [p.name for p in together] == ["tiny-seed3.mcap", "tiny-seed4.mcap"]
    for a, b in zip(together, alone, strict=True):
        assert a.read_bytes() == b.read_bytes()
        assert (
            a.with_suffix(".recipe.json").read_text() == b.with_suffix(".recipe.json").read_text()
        )
    assert together[0].read_bytes() != together[1].read_bytes()


def test_current_simulations_are_reused(tmp_path: Path) -> None:
    sims = _sims(tmp_path)
    first = ensure_simulations(sims[:1], workers=2)
    stamp = first[0].stat().st_mtime_ns
    assert all(not s.is_current() for s in sims[1:])
    ensure_simulations(sims, workers=2)
    assert first[0].stat().st_mtime_ns == stamp
    assert all(s.is_current() for s in sims)
