"""Benchmark of the `features` and `fuse` stages: keyframes per second and peak memory.

Keyframes are the first --keyframes ping pairs (every --every-th) of a simulated mission,
rendered into memory first, so the figures are the stages' own cost (targets, issue 5:
at least 100 keyframes per second each, two images per keyframe, on the 2-core machine).

    .venv/bin/python benchmarks/bench_features_fuse.py --scene marina --keyframes 100

Prints one JSON document: keyframes/s (best of --repeat), features and fused points per
keyframe, tracemalloc peak of each stage for half and all of the keyframes.
"""

from __future__ import annotations

import argparse
import json
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]

from sonarmap.schemas.sonar import KeyframeImages  # noqa: E402
from sonarmap.sim.config import MissionConfig, SimConfig  # noqa: E402
from sonarmap.sim.dataset import simulate  # noqa: E402
from sonarmap.sim.scene import load_scene  # noqa: E402
from sonarmap.stages.features.stage import FeaturesConfig, features_table  # noqa: E402
from sonarmap.stages.fuse.stage import FuseConfig, fuse_table  # noqa: E402


def _best(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def _peak(fn: Callable[[], Any]) -> int:
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="marina")
    ap.add_argument("--keyframes", type=int, default=100)
    ap.add_argument("--every", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()

    cfg = SimConfig(mission=MissionConfig(n_goals=50))
    run = simulate(load_scene(REPO / "configs" / "scenes" / f"{args.scene}.yaml"), cfg, args.seed)
    idx = list(range(0, run.n_frames, args.every))[: args.keyframes]
    frames = []
    for k, i in enumerate(idx):
        f = run.frame(i)
        frames.append(KeyframeImages(k, f.t_ns, f.horizontal, f.vertical))
    sensors = {
        s: {"T_base_sonar": run.T_base_sonar[s].tolist()} for s in ("horizontal", "vertical")
    }
    f_cfg, u_cfg = FeaturesConfig(), FuseConfig()
    n = len(frames)

    feat_s, feats = _best(lambda: features_table(frames, f_cfg), args.repeat)
    fuse_s, fused = _best(lambda: fuse_table(frames, feats, sensors, u_cfg), args.repeat)
    half = frames[: n // 2]
    feats_half = features_table(half, f_cfg)
    memory = {
        "features_peak_mb": {
            "half": round(_peak(lambda: features_table(half, f_cfg)) / 2**20, 1),
            "all": round(_peak(lambda: features_table(frames, f_cfg)) / 2**20, 1),
        },
        "fuse_peak_mb": {
            "half": round(_peak(lambda: fuse_table(half, feats_half, sensors, u_cfg)) / 2**20, 1),
            "all": round(_peak(lambda: fuse_table(frames, feats, sensors, u_cfg)) / 2**20, 1),
        },
    }
    print(
        json.dumps(
            {
                "scene": args.scene,
                "keyframes": n,
                "image_shape": list(frames[0].horizontal.image.shape),
                "features_kf_per_s": round(n / feat_s, 1),
                "fuse_kf_per_s": round(n / fuse_s, 1),
                "features_per_kf": round(feats.num_rows / n, 1),
                "fused_per_kf": round(fused.num_rows / n, 1),
                **memory,
            }
        )
    )


if __name__ == "__main__":
    main()
