"""The graph runner (issue 41): the whole pipeline cold with 1 and 2 workers, its
critical path, the demo cold and the demo fully cached, each figure beside its goal.

- cold: `sonarmap run` of the default marina (seed 0, 175 keyframes) into a fresh store
  (the model copied in from the model cache), with `--workers 1` and `--workers 2`;
  keyframes/s = keyframes / the process's wall time (imports and model copy included).
- critical path: the longest chain of stages through the graph, weighted by each stage's
  seconds in the 1-worker run (where a stage's seconds are its own); the map's critical
  path leaves out the figure stages (nothing waits for them).
- no figures: the 2-worker cold run again with `--no-figures`.
- demo: `sonarmap demo` in a fresh folder (simulation, shipped model, every stage).
- cached: `sonarmap demo` again on that folder: every stage a hit, the whole process.

The machine is shared: the 1-minute load average is printed beside the figures.

    .venv/bin/python benchmarks/bench_graph_runner.py [--dataset D.mcap] [--skip-demo]
        [--set classify.model=DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
GOAL_KEYFRAMES_PER_S = 15.0
GOAL_DEMO_S = 50.0
GOAL_CACHED_S = 0.5


def _sonarmap(*args: str) -> tuple[float, str]:
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "pipeline", *args], capture_output=True, text=True, cwd=ROOT
    )
    if proc.returncode != 0:
        raise SystemExit(
            f"sonarmap {' '.join(args)}: exit {proc.returncode}: {proc.stderr[-2000:]}"
        )
    return time.perf_counter() - t0, proc.stdout


def _cold(dataset: Path, workers: int, sets: list[str], *extra: str) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-graph-") as tmp:
        args = ["run", str(dataset), "--store", f"{tmp}/store", "--json", "--workers", str(workers)]
        wall, out = _sonarmap(*args, *extra, *(a for item in sets for a in ("--set", item)))
    doc = json.loads(out)
    keyframes = doc["summary"]["keyframes"]
    return {
        "wall_s": round(wall, 2),
        "keyframes": keyframes,
        "keyframes_per_s": round(keyframes / wall, 1),
        "stages_s": {s["stage"]: round(float(s["seconds"]), 2) for s in doc["stages"]},
        "load_average_1min": round(os.getloadavg()[0], 2),
    }


def critical_path(stages_s: dict[str, float], figures: bool = True) -> tuple[float, list[str]]:
    """The longest chain of stages (seconds, names) through the real pipeline's graph
    (figures=False: without the figure stages)."""
    sys.path.insert(0, str(ROOT))
    from pipeline.engine.registry import default_graph, without_figures

    stages = default_graph().stages
    best: dict[str, tuple[float, list[str]]] = {}
    for stage in stages if figures else without_figures(stages):  # plan order: upstream first
        ups = [best[u] for u in stage.upstream if u in best]
        before = max(ups, default=(0.0, []))
        best[stage.name] = (before[0] + stages_s.get(stage.name, 0.0), [*before[1], stage.name])
    seconds, chain = max(best.values())
    return round(seconds, 2), chain


def _demo() -> dict:
    out: dict = {}
    with tempfile.TemporaryDirectory(prefix="bench-graph-demo-") as tmp:
        args = ["demo", "--out", f"{tmp}/demo", "--store", f"{tmp}/store", "--json"]
        args += ["--set", f"training.directory={tmp}/training"]
        wall, _ = _sonarmap(*args)
        out["demo_s"] = round(wall, 1)
        out["demo_s_goal"] = f"<= {GOAL_DEMO_S:g}"
        out["demo_load_average_1min"] = round(os.getloadavg()[0], 2)
        runs = [_sonarmap(*args)[0] for _ in range(5)]
    out["cached_demo_s"] = round(statistics.median(runs), 3)
    out["cached_demo_s_goal"] = f"<= {GOAL_CACHED_S:g}"
    out["cached_runs_s"] = [round(r, 3) for r in runs]
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", type=Path, default=None, help="default: the demo's marina")
    ap.add_argument("--skip-demo", action="store_true", help="neither demo figure")
    ap.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        help="config override of the cold runs, e.g. classify.model=DIR (no training)",
    )
    args = ap.parse_args()
    if args.dataset is None:
        sys.path.insert(0, str(ROOT))
        from pipeline.training.datasets import ensure_simulation, scene_path

        args.dataset = ensure_simulation(
            scene_path("marina"), 0, ROOT / "data/demo/marina-seed0.mcap"
        )
    one, two = _cold(args.dataset, 1, args.sets), _cold(args.dataset, 2, args.sets)
    no_figures = _cold(args.dataset, 2, args.sets, "--no-figures")
    seconds, chain = critical_path(one["stages_s"])
    map_seconds, map_chain = critical_path(one["stages_s"], figures=False)
    report = {
        "dataset": str(args.dataset),
        "keyframes": one["keyframes"],
        "one_worker": one,
        "two_workers": two,
        "keyframes_per_s": two["keyframes_per_s"],
        "keyframes_per_s_goal": f">= {GOAL_KEYFRAMES_PER_S:g}",
        "speedup_2_over_1": round(one["wall_s"] / two["wall_s"], 2),
        "critical_path_s": seconds,
        "critical_path": " -> ".join(f"{s} {one['stages_s'][s]:.1f}" for s in chain),
        "map_critical_path_s": map_seconds,
        "map_critical_path": " -> ".join(f"{s} {one['stages_s'][s]:.1f}" for s in map_chain),
        "two_workers_no_figures": no_figures,
        **({} if args.skip_demo else _demo()),
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
