"""Simulator throughput: the default marina mission end to end (render + serialise +
zstd + write), peak memory and file size.

Target (issue 3): >= 20 frame pairs (two sonars + labels + truth angles + navigation)
per second on the 2-core machine. The machine is shared, so the CPU time (both cores,
open3d casts with 2 threads) and the load average are printed beside the wall-clock rate. Usage: `python benchmarks/bench_simulate.py
[--duration-s S] [--seed N] [--scene FILE]`; prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default=str(ROOT / "configs" / "scenes" / "marina.yaml"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration-s", type=float, default=None)
    ap.add_argument("--workers", type=int, default=1, help="render threads (the CLI uses 1)")
    args = ap.parse_args()

    from pipeline.formats.simulation import write_simulation
    from sim.config import MissionConfig, SimConfig
    from sim.dataset import simulate
    from sim.scene import load_scene

    scene_path = Path(args.scene)
    load_before = os.getloadavg()[0]
    cpu0 = time.process_time()
    t0 = time.perf_counter()
    config = SimConfig(mission=MissionConfig(duration_s=args.duration_s))
    run = simulate(load_scene(scene_path), config, args.seed)
    t_plan = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        info = write_simulation(
            run, Path(tmp) / "bench.mcap", scene_yaml=scene_path.read_text(), workers=args.workers
        )
    total = time.perf_counter() - t0
    cpu = time.process_time() - cpu0
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        json.dumps(
            {
                "benchmark": "simulate",
                "scene": run.world.scene.name,
                "workers": args.workers,
                "n_frames": run.n_frames,
                "mission_s": round(run.path.duration_s, 1),
                "plan_s": round(t_plan, 3),
                "write_s": round(info["seconds"], 2),
                "total_s": round(total, 2),
                "frame_pairs_per_s": round(run.n_frames / info["seconds"], 1),
                "file_mb": round(info["bytes"] / 1e6, 1),
                "kb_per_frame": round(info["bytes"] / 1e3 / run.n_frames, 1),
                "cpu_s": round(cpu, 2),
                "frame_pairs_per_cpu_s": round(run.n_frames / cpu, 1),
                "loadavg_1min_before": round(load_before, 2),
                "loadavg_1min_after": round(os.getloadavg()[0], 2),
                "peak_rss_mb": round(rss_mb, 0),
                "target_frame_pairs_per_s": 20,
            }
        )
    )


if __name__ == "__main__":
    main()
