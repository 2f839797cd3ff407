"""Dense submaps on the default marina, cold: frame pairs per second and peak memory.

Issue 41's speed target (issue 21 asked for 100 and stayed out of reach): the whole
pipeline on all 1,441 frame pairs of the default marina (seed 0, 175 keyframes at 2 m),
`keyframes.submap_stride=1` (every pair between two keyframes is a submap frame), cold
store: >= 60 frame pairs/s through features +
fuse + classify + infer (the keyframe stages) + submaps + voxelize; keyframes, slam and
training excluded (a fresh store holding only the trained model, copied from the
machine's model cache, as bench_pipeline does), evaluate not run. Peak RSS <= 1.5 GB.

Each repeat runs the pipeline (`--until voxelize`) in a fresh child process, which
records every stage's wall and CPU time (`time.process_time`) and the process's peak
RSS (`ru_maxrss`) after each stage, so the peak can be traced to the stage that set it.
Prints medians over --repeat beside their goals.

    .venv/bin/python benchmarks/bench_submaps.py [--repeat 3] [--stride 1] [--dataset D.mcap]
        [--set section.field=value ...]

Without the demo's recording (`make demo`), the default marina is simulated once into
data/bench/marina-seed0.mcap (`sonarmap simulate`, same scene and seed: same bytes).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
GOAL_FRAME_PAIRS_PER_S = 60.0
GOAL_PEAK_RSS_MIB = 1536.0
TIMED = ("features", "fuse", "classify", "infer", "submaps", "voxelize")
"""The stages the target times (keyframes and slam are excluded)."""


def _child(dataset: Path, store: Path, stride: int, overrides: list[str]) -> None:
    """One cold run in this process; prints per-stage wall, CPU and peak RSS as JSON."""
    from sonarmap.pipeline.api import RunRequest, run_dataset

    marks: dict[str, float] = {}
    stages: dict[str, dict[str, float]] = {}
    tree = _TreeRss()

    def on_start(item) -> None:
        marks["wall"], marks["cpu"] = time.perf_counter(), time.process_time()

    def on_stage(result) -> None:
        stages[result.stage] = {
            "wall_s": time.perf_counter() - marks["wall"],
            "cpu_s": time.process_time() - marks["cpu"],
            "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "tree_peak_rss_mib": tree.peak_mib_since_last(),
            "computed": result.status != "hit",
        }

    request = RunRequest(
        dataset=dataset,
        overrides=[f"keyframes.submap_stride={stride}", *overrides],
        store_dir=store,
        until="voxelize",
    )
    try:
        _, summary = run_dataset(request, on_start=on_start, on_stage=on_stage)
    finally:
        tree.stop()
    frames = _submap_frames(store)
    workers = _workers(overrides, frames["submap_frames"])
    print(json.dumps({"stages": stages, "keyframes": summary["keyframes"], **frames, **workers}))


class _TreeRss:
    """Peak resident memory of this process and its children together (the `submaps`
    workers run beside it), sampled every 50 ms from /proc. ru_maxrss cannot give it:
    a child's counts the parent's memory at the fork that started it."""

    def __init__(self) -> None:
        self._peak = self._last = 0.0
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()

    @staticmethod
    def _rss_mib(pid: int) -> float:
        try:
            for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
        except OSError:
            pass
        return 0.0

    def _children(self) -> list[int]:
        me = os.getpid()
        out = []
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                if int(stat.read_text().rsplit(")", 1)[1].split()[1]) == me:
                    out.append(int(stat.parent.name))
            except (OSError, ValueError, IndexError):
                continue
        return out

    def _sample(self) -> None:
        while not self._done.wait(0.05):
            total = self._rss_mib(os.getpid()) + sum(map(self._rss_mib, self._children()))
            self._peak = max(self._peak, total)
            self._last = max(self._last, total)

    def peak_mib_since_last(self) -> float:
        """Peak since the previous call (or the start)."""
        peak, self._last = self._last, 0.0
        return round(peak, 1)

    def stop(self) -> None:
        self._done.set()
        self._thread.join()


def _workers(overrides: list[str], frames: int) -> dict[str, int]:
    """The processes `submaps` mapped in (1: this one, no workers)."""
    from sonarmap.stages.submaps.config import SubmapsConfig
    from sonarmap.stages.submaps.workers import worker_count

    setting = SubmapsConfig().workers
    for item in overrides:
        if item.startswith("submaps.workers="):
            value = item.split("=", 1)[1]
            setting = None if value in ("null", "None", "") else int(value)
    return {"workers": worker_count(setting, frames)}


def _submap_frames(store: Path) -> dict[str, int]:
    """Rows of the run's submap frames and points (from the artifact's manifest)."""
    manifest = next((store / "submaps").glob("*/manifest.json"))
    outputs = json.loads(manifest.read_text()).get("outputs", {})
    return {
        "submap_frames": int(outputs["frames"]["rows"]),
        "submap_points": int(outputs["points"]["rows"]),
    }


def _dataset(path: Path) -> Path:
    """`path`, or the default marina simulated into data/bench/ when it does not exist."""
    if path.is_file():
        return path
    simulated = ROOT / "data/bench/marina-seed0.mcap"
    if not simulated.is_file():
        simulated.parent.mkdir(parents=True, exist_ok=True)
        cmd = [sys.executable, "-m", "sonarmap.pipeline", "simulate", "-o", str(simulated), "--seed", "0"]
        subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True)
    return simulated


def _one_run(dataset: Path, models: list[Path], stride: int, overrides: list[str]) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench_submaps_") as tmp:
        store = Path(tmp) / "store"
        for manifest in models:  # the model only: every mapping stage is computed
            shutil.copytree(manifest.parent, store / "train" / manifest.parent.name)
        cmd = [sys.executable, __file__, "--child", str(dataset), str(store), str(stride)]
        cmd += overrides
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, check=True)
        doc = json.loads(proc.stdout.strip().splitlines()[-1])
        doc["process_wall_s"] = time.perf_counter() - t0
        return doc


def _median(runs: list[dict], fn) -> float:
    return statistics.median(fn(r) for r in runs)


def _report(runs: list[dict], args: argparse.Namespace) -> dict:
    first = runs[0]
    pairs = first["keyframes"] + first["submap_frames"]
    wall = _median(runs, lambda r: sum(r["stages"][s]["wall_s"] for s in TIMED))
    cpu = _median(runs, lambda r: sum(r["stages"][s]["cpu_s"] for s in TIMED))
    sub_wall = _median(runs, lambda r: r["stages"]["submaps"]["wall_s"])
    sub_cpu = _median(runs, lambda r: r["stages"]["submaps"]["cpu_s"])
    rss = _median(runs, lambda r: max(s["peak_rss_mib"] for s in r["stages"].values()))
    tree_rss = _median(runs, lambda r: max(s["tree_peak_rss_mib"] for s in r["stages"].values()))
    return {
        "dataset": str(args.dataset),
        "stride": args.stride,
        "overrides": args.set,
        "repeat": args.repeat,
        "keyframes": first["keyframes"],
        "submap_frames": first["submap_frames"],
        "submap_points": first["submap_points"],
        "frame_pairs": pairs,
        "stages_wall_s": {
            s: round(_median(runs, lambda r, s=s: r["stages"][s]["wall_s"]), 2)
            for s in first["stages"]
        },
        "stages_cpu_s": {
            s: round(_median(runs, lambda r, s=s: r["stages"][s]["cpu_s"]), 2)
            for s in first["stages"]
        },
        "peak_rss_mib_after": {
            s: round(_median(runs, lambda r, s=s: r["stages"][s]["peak_rss_mib"]), 1)
            for s in first["stages"]
        },
        "timed_wall_s": round(wall, 2),
        "timed_cpu_s": round(cpu, 2),
        "frame_pairs_per_s": round(pairs / wall, 1),
        "frame_pairs_per_s_goal": GOAL_FRAME_PAIRS_PER_S,
        "frame_pairs_per_cpu_s": round(pairs / cpu, 1),
        "submaps_frames_per_s": round(first["submap_frames"] / sub_wall, 1),
        "submaps_frames_per_cpu_s": round(first["submap_frames"] / sub_cpu, 1),
        "peak_rss_mib": round(rss, 1),
        "peak_rss_mib_goal": GOAL_PEAK_RSS_MIB,
        "submaps_workers": first["workers"],
        "peak_rss_mib_with_workers": round(tree_rss, 1),
        "peak_rss_mib_with_workers_after": {
            s: round(_median(runs, lambda r, s=s: r["stages"][s]["tree_peak_rss_mib"]), 1)
            for s in first["stages"]
        },
        "process_wall_s": round(_median(runs, lambda r: r["process_wall_s"]), 2),
        "load_average_1min": os.getloadavg()[0],
    }


def main() -> None:
    if len(sys.argv) >= 5 and sys.argv[1] == "--child":
        _child(Path(sys.argv[2]), Path(sys.argv[3]), int(sys.argv[4]), sys.argv[5:])
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", type=Path, default=ROOT / "data/demo/marina-seed0.mcap")
    ap.add_argument("--model-cache", type=Path, default=ROOT / "data/training/store")
    ap.add_argument("--stride", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--set", action="append", default=[], help="config override k=v (repeatable)")
    args = ap.parse_args()
    args.dataset = _dataset(args.dataset)
    models = sorted((args.model_cache / "train").glob("*/manifest.json"))
    if not models:
        raise SystemExit(f"{args.model_cache}: no trained model (run `make demo` once first)")
    runs = [_one_run(args.dataset, models, args.stride, args.set) for _ in range(args.repeat)]
    print(json.dumps(_report(runs, args), indent=2))


if __name__ == "__main__":
    main()
