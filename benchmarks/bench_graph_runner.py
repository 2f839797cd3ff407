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
- cached: `sonarmap demo` again on that folder, as a user types it (text output): every
  stage a hit, the whole process's wall time, median of 5, with PYTHONDONTWRITEBYTECODE
  and no `.pyc` of the checkout (it removes them), and without it, reading the `.pyc`
  files as installed copies and CI do; `--json` beside it (it also reads
  objects.parquet for the classification scores).
- `--cached-only`: only the cached figures, on an existing demo folder and store
  (default: data/demo and data/store, as `sonarmap demo` leaves them).

The machine is shared: the 1-minute load average is printed beside the figures.

    .venv/bin/python benchmarks/bench_graph_runner.py [--dataset D.mcap] [--skip-demo]
        [--set classify.model=DIR]
    .venv/bin/python benchmarks/bench_graph_runner.py --cached-only [--out data/demo]
        [--store data/store]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
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


def _sonarmap(*args: str, env: dict[str, str] | None = None) -> tuple[float, str]:
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "sonarmap.pipeline", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=env,
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
    from sonarmap.pipeline.graph import default_graph, without_figures

    stages = default_graph().stages
    best: dict[str, tuple[float, list[str]]] = {}
    for stage in stages if figures else without_figures(stages):  # plan order: upstream first
        ups = [best[u] for u in stage.upstream if u in best]
        before = max(ups, default=(0.0, []))
        best[stage.name] = (before[0] + stages_s.get(stage.name, 0.0), [*before[1], stage.name])
    seconds, chain = max(best.values())
    return round(seconds, 2), chain


def _drop_project_bytecode() -> None:
    """Remove the checkout's own `.pyc` files (they are caches: the next run without
    PYTHONDONTWRITEBYTECODE writes them again); the libraries' stay, as pip wrote them."""
    for package in ("pipeline", "stages", "schemas", "sim"):
        for cache in (ROOT / package).rglob("__pycache__"):
            shutil.rmtree(cache, ignore_errors=True)


def cached_demo(args: list[str]) -> dict:
    """`sonarmap demo ARGS` on a folder where every stage is cached: median of 5 whole
    processes each, (1) with PYTHONDONTWRITEBYTECODE=1 and none of the checkout's `.pyc`
    files (every project module compiled in every run, as in a session that sets it),
    (2) without it, the `.pyc` files written (an installed copy, CI), (3) `--json`."""
    plain = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    _sonarmap(*args, env=plain)  # every stage a hit from here on
    out: dict = {}
    _drop_project_bytecode()
    for name, extra, env in (
        ("cached_demo_s_no_pyc", [], {**plain, "PYTHONDONTWRITEBYTECODE": "1"}),
        ("cached_demo_s", [], plain),
        ("cached_demo_json_s", ["--json"], plain),
    ):
        if env is plain:
            _sonarmap(*args, *extra, env=env)  # writes the .pyc files the runs then read
        runs = [_sonarmap(*args, *extra, env=env)[0] for _ in range(5)]
        out[name] = round(statistics.median(runs), 3)
        out[f"{name}_runs"] = [round(r, 3) for r in runs]
    out["cached_demo_s_goal"] = f"<= {GOAL_CACHED_S:g}"
    out["cached_load_average_1min"] = round(os.getloadavg()[0], 2)
    return out


def _demo() -> dict:
    out: dict = {}
    with tempfile.TemporaryDirectory(prefix="bench-graph-demo-") as tmp:
        args = ["demo", "--out", f"{tmp}/demo", "--store", f"{tmp}/store"]
        args += ["--set", f"training.directory={tmp}/training"]
        wall, _ = _sonarmap(*args, "--json")
        out["demo_s"] = round(wall, 1)
        out["demo_s_goal"] = f"<= {GOAL_DEMO_S:g}"
        out["demo_load_average_1min"] = round(os.getloadavg()[0], 2)
        out.update(cached_demo(args))
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
    ap.add_argument("--cached-only", action="store_true", help="only the cached demo figures")
    ap.add_argument("--out", default="data/demo", help="--cached-only: the demo's folder")
    ap.add_argument("--store", default="data/store", help="--cached-only: its store")
    args = ap.parse_args()
    if args.cached_only:
        demo = ["demo", "--out", args.out, "--store", args.store]
        print(json.dumps(cached_demo(demo), indent=2))
        return 0
    if args.dataset is None:
        from sonarmap.pipeline.training.datasets import ensure_simulation, scene_path

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
