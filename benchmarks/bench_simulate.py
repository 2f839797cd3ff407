"""Simulator throughput: the default marina mission end to end (render + serialise +
zstd + write), CPU time, peak memory and file size, serially and with render workers.

Goal (issue 22): >= 80 frame pairs (two sonars + labels + truth angles + navigation) per
second on the 2-core machine; "now" (issue 22) was 32 frame pairs/s with one worker. The
machine is shared, so each figure is the median of `--repeat` runs, with the CPU time of
this process and of its render workers (`resource.getrusage`) and the load average
beside it. `cpu_bound_frame_pairs_per_s` is what the CPU time allows on two idle cores:
n / max(writer CPU, all CPU / 2). Usage: `python benchmarks/bench_simulate.py
[--duration-s S] [--seed N] [--scene FILE] [--workers 1,2] [--repeat 3] [--sonar NAME]`;
prints one JSON object.

Measured 2026-12-01, issue 22 (default marina, 1441 frame pairs, seed 0, medians of 3,
the shared 2-core box at load 5-9; "base" is the tree before this work, from `git archive`):
- base, serial: 19.8 frame pairs/s, 47.1 CPU s (30.6 frame pairs per CPU s).
- now, serial: 19.3 frame pairs/s, 50.7 CPU s (28.4 per CPU s); same bytes.
- now, 2 render workers: 16.9 frame pairs/s; writer 17.7 + workers 50.4 = 68.1 CPU s;
  `cpu_bound_frame_pairs_per_s` 42.3. The workers' rendering cost 35 ms CPU per frame
  pair against 23-26 ms in one process, so on this (virtual, loaded) box the processes
  slow each other down and the goal is not met.
- where a frame pair's time goes (serial, cProfile / per-step timers): rendering about
  25 ms CPU (open3d ray casts 7-8, strongest return per pixel 6, noise and speckle 4.5-5,
  splatting 2.5, `np.bincount` 2.3, per-ray intensity 2), writing about 16 ms (zstd level
  3 of 3.7 MB 12.6, chunk CRC 2, buffer writes 1.5). Both bound the bytes: the zstd level,
  the chunk size and every random draw are part of the file.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

GOAL_FRAME_PAIRS_PER_S = 80.0
NOW_FRAME_PAIRS_PER_S = 32.0
"""Issue 22's "now": the default marina with one worker."""


def _cpu_s(who: int) -> float:
    ru = resource.getrusage(who)
    return ru.ru_utime + ru.ru_stime


def _once(scene_path: Path, args: argparse.Namespace, workers: int) -> dict[str, float]:
    """One simulation into a temporary file: wall and CPU seconds, file size."""
    from sonarmap.pipeline.formats.simulation import write_simulation
    from sonarmap.sim.config import MissionConfig, SimConfig
    from sonarmap.sim.dataset import simulate
    from sonarmap.sim.scene import load_scene

    config = SimConfig(mission=MissionConfig(duration_s=args.duration_s))
    if args.sonar:
        from sonarmap.pipeline.training.sim_sensors import with_sensors

        config = with_sensors(config, {"horizontal": args.sonar, "vertical": args.sonar})
    run = simulate(load_scene(scene_path), config, args.seed)
    self0, kids0 = _cpu_s(resource.RUSAGE_SELF), _cpu_s(resource.RUSAGE_CHILDREN)
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        info = write_simulation(
            run, Path(tmp) / "bench.mcap", scene_yaml=scene_path.read_text(), workers=workers
        )
    writer = _cpu_s(resource.RUSAGE_SELF) - self0
    render = _cpu_s(resource.RUSAGE_CHILDREN) - kids0
    n = run.n_frames
    return {
        "n_frames": n,
        "write_s": info["seconds"],
        "frame_pairs_per_s": n / info["seconds"],
        "writer_cpu_s": writer,
        "worker_cpu_s": render,
        "cpu_s": writer + render,
        "frame_pairs_per_cpu_s": n / (writer + render),
        "cpu_bound_frame_pairs_per_s": n / max(writer, (writer + render) / 2),
        "file_mb": info["bytes"] / 1e6,
        "loadavg_1min": load,
    }


def _median(rows: list[dict[str, float]]) -> dict[str, float]:
    return {k: round(statistics.median(r[k] for r in rows), 2) for k in rows[0]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default=str(ROOT / "configs" / "scenes" / "marina.yaml"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration-s", type=float, default=None)
    ap.add_argument("--sonar", default=None, help="sensor of both sonars (sonarmap simulate)")
    ap.add_argument("--workers", default="1,2", help="render processes to compare, e.g. 1,2")
    ap.add_argument("--repeat", type=int, default=3, help="runs per worker count (median)")
    args = ap.parse_args()
    scene_path = Path(args.scene)
    counts = [int(w) for w in args.workers.split(",")]
    # Interleaved, so a change in the machine's load touches every worker count alike.
    runs: dict[int, list[dict[str, float]]] = {w: [] for w in counts}
    for _ in range(args.repeat):
        for w in counts:
            runs[w].append(_once(scene_path, args, w))
    by_workers = {str(w): _median(rows) for w, rows in runs.items()}
    best = max(by_workers.values(), key=lambda r: r["frame_pairs_per_s"])
    report = {
        "benchmark": "simulate",
        "scene": scene_path.stem,
        "repeat": args.repeat,
        "by_workers": by_workers,
        "frame_pairs_per_s": best["frame_pairs_per_s"],
        "frame_pairs_per_s_goal": GOAL_FRAME_PAIRS_PER_S,
        "frame_pairs_per_s_now": NOW_FRAME_PAIRS_PER_S,
        "ratio_to_now": round(best["frame_pairs_per_s"] / NOW_FRAME_PAIRS_PER_S, 2),
        "cpu_bound_frame_pairs_per_s": best["cpu_bound_frame_pairs_per_s"],
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024),
    }
    print(json.dumps(report))


if __name__ == "__main__":
    main()
