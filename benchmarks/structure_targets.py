"""Issue 20's whole-structure targets, scene by scene, printed beside their goals.

For each recording, `sonarmap run` at 4 m keyframes with true poses (and, with --slam,
with SLAM poses too), then from `metrics.json`:

- all-structure accurate voxels, semantic / standard (goal >= 5x);
- completeness of the visible structure, semantic / standard (goal >= 3x);
- inferred-point median error over the fused points' (goal <= 1.2x) and in metres
  (goal <= 0.10 m), all structure, at the SLAM-aligned positions with SLAM poses;
- the largest inferred / fused ratio of any class that was inferred, by assigned class
  (`per_class.assigned_classes`; goal <= 1.5x).

    .venv/bin/python benchmarks/structure_targets.py [D.mcap ...] [--slam] [--set k=v ...]

Without recordings it simulates seed 0 of the default marina and of the shipyard, quay,
basin and terminal scenes (20 goals each) into data/bench/structure/ once (same scene and
seed: same bytes). Stages already in the store are reused, so a rerun takes seconds.
Prints one JSON document on stdout and the table on stderr.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_SCENES = ("marina", "shipyard", "quay", "basin", "terminal")
GOALS = {"accurate": 5.0, "completeness": 3.0, "error_ratio": 1.2, "inferred_m": 0.10, "class": 1.5}


def _recordings(args: argparse.Namespace) -> list[Path]:
    if args.datasets:
        return [Path(d) for d in args.datasets]
    from sonarmap.pipeline.training.datasets import ensure_simulation, scene_path

    out = ROOT / "data" / "bench" / "structure"
    return [
        ensure_simulation(scene_path(s), 0, out / f"{s}-goals20-seed0.mcap", goals=20)
        for s in DEFAULT_SCENES
    ]


def _run(dataset: Path, store: Path, slam: bool, extra: list[str]) -> dict[str, Any]:
    sets = ["keyframes.spacing_m=4", *([] if slam else ["slam.mode=ground_truth"]), *extra]
    cmd = [sys.executable, "-m", "sonarmap.pipeline", "run", str(dataset), "--store", str(store)]
    cmd += ["--json", "-q", *(a for s in sets for a in ("--set", s))]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"{dataset}: sonarmap run failed: {proc.stderr.strip().splitlines()[-1]}")
    return json.loads(proc.stdout)["summary"]["metrics"]


def _ratio(num: float | None, den: float | None) -> float | None:
    return num / den if num is not None and den else None


def _figures(metrics: dict[str, Any]) -> dict[str, Any]:
    per_class = metrics["per_class"]
    whole = per_class["classes"]["all_structure"]
    std, sem = whole["standard"], whole["semantic"]
    fused_m = std["median_error_m"]  # at the SLAM-aligned positions when there was SLAM
    inferred_m = (whole.get("inferred") or {}).get("median_error_m")
    budget = {
        name: c["inferred_over_fused"]
        for name, c in (per_class.get("assigned_classes") or {}).items()
        if c.get("inferred_points") and c.get("inferred_over_fused") is not None
    }
    worst = max(budget, key=budget.__getitem__) if budget else None
    return {
        "accurate": _ratio(sem["accurate_voxels"], std["accurate_voxels"]),
        "completeness": _ratio(sem["completeness"], std["completeness"]),
        "error_ratio": _ratio(inferred_m, fused_m),
        "inferred_m": inferred_m,
        "frame": per_class.get("frame"),
        "class": budget.get(worst) if worst else None,
        "worst_class": worst,
        "inferred_over_fused_by_class": budget,
    }


def _mark(key: str, value: float | None) -> str:
    if value is None:
        return "-"
    ok = value >= GOALS[key] if key in ("accurate", "completeness") else value <= GOALS[key]
    return f"{value:.3f}" + ("" if ok else " ✗")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("datasets", nargs="*", help="recordings (default: simulated scenes)")
    ap.add_argument("--store", default=str(ROOT / "data" / "store"))
    ap.add_argument("--slam", action="store_true", help="also with SLAM poses")
    ap.add_argument("--set", dest="sets", action="append", default=[], help="section.field=value")
    args = ap.parse_args()
    rows = []
    for dataset in _recordings(args):
        for slam in (False, True) if args.slam else (False,):
            figures = _figures(_run(dataset, Path(args.store), slam, args.sets))
            rows.append({"dataset": dataset.name, "poses": "slam" if slam else "true", **figures})
    print(json.dumps({"goals": GOALS, "overrides": args.sets, "rows": rows}, indent=2))
    head = "| dataset | poses | accurate (≥ 5x) | completeness (≥ 3x) | inferred/fused (≤ 1.2x)"
    print(head + " | inferred m (≤ 0.10) | worst class (≤ 1.5x) |", file=sys.stderr)
    for r in rows:
        cells = [_mark(k, r[k]) for k in ("accurate", "completeness", "error_ratio", "inferred_m")]
        worst = f"{r['worst_class']} {_mark('class', r['class'])}" if r["worst_class"] else "-"
        print(f"| {r['dataset']} | {r['poses']} | " + " | ".join(cells) + f" | {worst} |",
              file=sys.stderr)  # fmt: skip


if __name__ == "__main__":
    main()
