"""Cost against false detections (issue 50, item 5): per stage CPU seconds and peak RSS.

One short mission (marina, seed 0, 4 goals by default) is mapped at increasing numbers
of false detections, flooded on purpose: the clean sensor with the features stage's
`intensity_floor` lowered and its `pfa` raised (CFAR then passes the speckle), and the
same mission rendered at Oculus-like image statistics (additive Weibull noise, mean
level 53, shape 1.2) with the default config. Each level runs in a fresh process and a
fresh store, every stage computed one after another in that process (`workers` 1,
figures off); around each stage the process's CPU time (user + system, its own and its
reaped children's) is read, and its peak RSS (VmHWM) reset before the stage and read
after it (`/proc/self/clear_refs`; where that is refused, the peak so far). The peak
includes what the stage loads and what the process held already (the interpreter, the
imports: about 0.2-0.5 GB).

Prints a table per level (features, fused points, objects, per stage CPU s and peak GB),
then per stage the growth exponent: the slope of log CPU seconds against log features
over the levels (1: linear; a stage near-constant in cost has a slope near 0), and the
same for peak RSS. One JSON document (`--json`) instead on request.

    .venv/bin/python -m benchmarks.bench_noise_cost                  # 4 goals, 5 levels
    .venv/bin/python -m benchmarks.bench_noise_cost --levels default,floor0,oculus
    .venv/bin/python -m benchmarks.bench_noise_cost --dataset data/demo/marina-seed0.mcap \
        --levels default                                              # the demo's ATE

Measured 2026-12-06 (2 shared cores; `--levels default,floor0,oculus`, 4 goals, seed 0),
per stage CPU s / peak GB, before = slam version 11's inputs (`--set
slam.outlier_radius_m=null --set slam.max_points_per_keyframe=null`), after = version 12:

    level   features  objects  slam before     slam after    total CPU before / after
    default  223,852      412  2.6 s / 0.48    1.9 s / 0.47  11.8 / 12.3 s
    floor0   402,096      613  22.1 s / 0.70   12.3 s / 0.63 34.8 / 24.1 s
    oculus 1,619,947   10,156  100.0 s / 1.30  9.1 s / 0.75  128.4 / 35.7 s

slam's growth exponent against features 1.71 -> 0.60 (its ATE on the Oculus-like level
0.47 -> 0.15 m, dead reckoning 0.10; clean 0.049 -> 0.051); every other stage's is at
most 1 (voxelize 0.92-1.02, evaluate 0.75-0.79, classify 0.56-0.66, fuse 0.51-0.53).
The Oculus-like level's peak is then classify's (1.1 GB, the process's torch included).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
OUT_DIR = ROOT / "data/bench/noise_cost"
OCULUS = {"noise_mean_level": 53.0, "noise_shape": 1.2}
"""Issue 50's Oculus-like sensor (background median ~42, speckle contrast 0.64)."""

LEVELS: dict[str, tuple[str, tuple[str, ...]]] = {
    # name: (sensor, features overrides)
    "default": ("clean", ()),
    "floor10": ("clean", ("features.intensity_floor=10",)),
    "floor5": ("clean", ("features.intensity_floor=5",)),
    "floor0": ("clean", ("features.intensity_floor=0",)),
    "floor0-pfa0.2": ("clean", ("features.intensity_floor=0", "features.pfa=0.2")),
    "oculus": ("oculus", ()),
}
STAGE_ORDER = ("keyframes", "features", "fuse", "classify", "slam", "infer", "submaps")
STAGE_ORDER += ("voxelize", "evaluate")


def _cpu_s() -> float:
    own, kids = (
        resource.getrusage(resource.RUSAGE_SELF),
        resource.getrusage(resource.RUSAGE_CHILDREN),
    )
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _reset_peak() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _peak_gb() -> float:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024**2
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2


def _find(doc: Any, key: str) -> Any:
    """The first value of `key` anywhere in a JSON document (None: absent)."""
    if isinstance(doc, dict):
        if key in doc:
            return doc[key]
        doc = list(doc.values())
    if isinstance(doc, list):
        for item in doc:
            found = _find(item, key)
            if found is not None:
                return found
    return None


def child(dataset: Path, store: Path, overrides: list[str]) -> dict[str, Any]:
    """Map `dataset` in this process, stage by stage: per stage CPU s and peak GB."""
    from sonarmap.pipeline.api import RunRequest, run_dataset
    from sonarmap.pipeline.engine.store.codecs import read_verified

    per: dict[str, dict[str, float]] = {}
    mark: dict[str, float] = {}
    resettable = _reset_peak()

    def on_start(item: Any) -> None:
        if resettable:
            _reset_peak()
        mark[item.stage.name] = _cpu_s()

    def on_stage(result: Any) -> None:
        if result.stage in mark and result.status == "computed":
            per[result.stage] = {
                "cpu_s": round(_cpu_s() - mark[result.stage], 2),
                "wall_s": round(float(result.seconds), 2),
                "peak_gb": round(_peak_gb(), 3),
            }

    request = RunRequest(dataset, overrides=overrides, store_dir=store, workers=1, figures=False)
    result, summary = run_dataset(request, on_start=on_start, on_stage=on_stage, scores=False)
    counts: dict[str, Any] = {
        "features": (summary.get("features") or {}).get("features"),
        "fused": (summary.get("fuse") or {}).get("fused"),
        "keyframes": summary.get("keyframes"),
    }
    objects = result.artifacts["classify"].manifest.get("outputs", {}).get("objects", {})
    counts["objects"] = objects.get("rows")
    from sonarmap.pipeline.graph import stage_by_name

    slam = stage_by_name("slam")
    out = next(o for o in slam.outputs if o.name == "summary")
    counts["slam_summary"] = read_verified(result.artifacts["slam"], out)
    counts["slam_ate_m"] = _find(summary.get("metrics"), "slam_ate_m")
    counts["median_m"] = (_find(summary.get("metrics"), "headline") or {}).get("median_m")
    return {"stages": per, "counts": counts, "peak_reset": resettable}


def _dataset(sensor: str, goals: int, seed: int) -> Path:
    from sonarmap.pipeline.training.datasets import ensure_simulation, scene_path
    from sonarmap.sim.config import SonarConfig

    draw = None
    if sensor == "oculus":
        sonar = {**OCULUS, "gain_db": 0.0, "tilt_deg": [0.0, 0.0, 0.0]}
        factor = {k: 1.0 for k in SonarConfig().reflectivity}
        draw = {"reflectivity_factor": factor, "horizontal": sonar, "vertical": sonar}
    out = OUT_DIR / f"marina-seed{seed}-g{goals}-{sensor}.mcap"
    return ensure_simulation(scene_path("marina"), seed, out, goals=goals, sensor=draw)


def _run_level(dataset: Path, overrides: tuple[str, ...]) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="bench_noise_cost_") as tmp:
        cmd = [sys.executable, "-m", "benchmarks.bench_noise_cost", "--child", str(dataset)]
        cmd += ["--store", str(Path(tmp) / "store")]
        # A training directory of its own, empty: the shipped model is found from its
        # lock, whatever recordings another simulator left in the user's cache (those
        # would be fingerprinted and the model trained again, inside the measurement).
        cmd += ["--set", f"training.directory={Path(tmp) / 'training'}"]
        for item in overrides:
            cmd += ["--set", item]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
        if proc.returncode != 0:
            raise SystemExit(f"level failed ({' '.join(cmd)}):\n{proc.stderr[-3000:]}")
        doc = json.loads(proc.stdout.strip().splitlines()[-1])
        doc["process_wall_s"] = round(time.perf_counter() - t0, 1)
        return doc


def slopes(rows: list[dict[str, Any]], field: str) -> dict[str, float | None]:
    """Per stage, the least-squares slope of log(field) on log(features) over the levels."""
    out: dict[str, float | None] = {}
    feats = np.array([r["counts"]["features"] for r in rows], dtype=float)
    for stage in STAGE_ORDER:
        vals = np.array([r["stages"].get(stage, {}).get(field, np.nan) for r in rows], float)
        ok = np.isfinite(vals) & (vals > 0) & (feats > 0)
        if ok.sum() < 2 or np.ptp(np.log(feats[ok])) < 1e-9:
            out[stage] = None
            continue
        out[stage] = round(float(np.polyfit(np.log(feats[ok]), np.log(vals[ok]), 1)[0]), 2)
    return out


def _table(rows: list[dict[str, Any]], names: list[str]) -> str:
    head = ["level", "features", "fused", "objects"]
    head += [f"{s[:8]} s/GB" for s in STAGE_ORDER] + ["total CPU s", "peak GB"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, r in zip(names, rows, strict=True):
        c, st = r["counts"], r["stages"]
        cells = [name, f"{c['features']:,}", f"{c['fused']:,}", f"{c['objects']:,}"]
        for s in STAGE_ORDER:
            v = st.get(s)
            cells.append("-" if v is None else f"{v['cpu_s']:.1f} / {v['peak_gb']:.2f}")
        cells.append(f"{sum(v['cpu_s'] for v in st.values()):.1f}")
        cells.append(f"{max(v['peak_gb'] for v in st.values()):.2f}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--store", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--set", action="append", default=[], help="extra override, all levels")
    ap.add_argument("--levels", default="default,floor10,floor5,floor0,oculus")
    ap.add_argument("--goals", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--dataset", type=Path, help="map this recording instead (clean levels)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if args.child is not None:
        print(json.dumps(child(args.child, args.store, args.set)))
        return 0
    names = [n for n in args.levels.split(",") if n]
    unknown = [n for n in names if n not in LEVELS]
    if unknown:
        raise SystemExit(f"unknown level(s) {unknown}; known: {', '.join(LEVELS)}")
    rows = []
    for name in names:
        sensor, overrides = LEVELS[name]
        dataset = args.dataset or _dataset(sensor, args.goals, args.seed)
        rows.append(_run_level(dataset, (*overrides, *args.set)))
        rows[-1]["level"] = name
        print(f"{name}: {rows[-1]['process_wall_s']} s", file=sys.stderr, flush=True)
    doc = {
        "load_average_1min": round(os.getloadavg()[0], 2),
        "levels": rows,
        "cpu_exponent": slopes(rows, "cpu_s"),
        "peak_exponent": slopes(rows, "peak_gb"),
    }
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    print(_table(rows, names))
    for field in ("cpu_exponent", "peak_exponent"):
        print(f"{field} (log-log slope against features):")
        print("  " + ", ".join(f"{k} {v}" for k, v in doc[field].items()))
    for name, r in zip(names, rows, strict=True):
        s = r["counts"]["slam_summary"]
        print(
            f"{name}: slam ATE {r['counts']['slam_ate_m']} m, median error"
            f" {r['counts']['median_m']}, slam points {s.get('points')}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
