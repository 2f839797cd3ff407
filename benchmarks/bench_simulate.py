"""Simulator throughput: the default marina mission end to end (render + serialise +
zstd + write), peak memory and file size.

Target (issue 3): >= 20 frame pairs (two sonars + labels + truth angles + navigation)
per second on the 2-core machine. Usage: `python benchmarks/bench_simulate.py
[--duration-s S] [--seed N] [--scene FILE]`; prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
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
    args = ap.parse_args()

    from pipeline.simulate import write_simulation
    from sim.config import MissionConfig, SimConfig
    from sim.dataset import simulate
    from sim.scene import load_scene

    scene_path = Path(args.scene)
    t0 = time.perf_counter()
    config = SimConfig(mission=MissionConfig(duration_s=args.duration_s))
    run = simulate(load_scene(scene_path), config, args.seed)
    t_plan = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        info = write_simulation(run, Path(tmp) / "bench.mcap", scene_yaml=scene_path.read_text())
    total = time.perf_counter() - t0
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        json.dumps(
            {
                "benchmark": "simulate",
                "scene": run.world.scene.name,
                "n_frames": run.n_frames,
                "mission_s": round(run.path.duration_s, 1),
                "plan_s": round(t_plan, 3),
                "write_s": round(info["seconds"], 2),
                "total_s": round(total, 2),
                "frame_pairs_per_s": round(run.n_frames / info["seconds"], 1),
                "file_mb": round(info["bytes"] / 1e6, 1),
                "kb_per_frame": round(info["bytes"] / 1e3 / run.n_frames, 1),
                "peak_rss_mb": round(rss_mb, 0),
                "target_frame_pairs_per_s": 20,
            }
        )
    )


if __name__ == "__main__":
    main()
