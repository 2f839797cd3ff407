"""Issue 39's frozen-model test: scenes written after the model froze, CNN beside oracle.

For each scene (default: every `configs/scenes/frozen/*.yaml`), seed 0 is simulated
with 8 goals into data/bench/frozen/ once, then mapped twice with 4 m keyframes and
true poses: with the classifier (CNN) and with the simulator's classes
(`classify.labels=ground_truth`, the oracle). The difference between the two is the
classifier's share of the loss; the oracle's own shortfall belongs to inference.

Per scene and labelling it prints, beside the goals:

- all-structure accurate voxels, semantic / standard (goal >= 5x);
- the inferred points' median error over the fused points' (goal <= 1.2x);
- per true class: the accurate-voxel gain;
- per assigned class: the inferred points' median error over its fused points' (the
  1.5x budget that decides which classes are inferred);
- the CNN's object confusion (true class -> assigned class counts).

    .venv/bin/python benchmarks/frozen_scenes.py [SCENE ...] [--store DIR] [--set k=v ...]
        [--labels cnn,oracle]

(`--labels cnn --set classify.model=DIR` scores another model; the oracle does not depend
on it.)

Prints one JSON document on stdout and the tables on stderr.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from collections import Counter
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
FROZEN = ROOT / "configs" / "scenes" / "frozen"
GOALS = {"accurate": 5.0, "error_ratio": 1.2}
LABELLINGS = {"cnn": [], "oracle": ["classify.labels=ground_truth"]}


def _recordings(scenes: list[str]) -> list[Path]:
    from sonarmap.pipeline.training.datasets import ensure_simulation, scene_path

    def path(scene: str) -> Path:  # a frozen scene's name first, then configs/scenes/
        frozen = FROZEN / f"{scene}.yaml"
        return frozen if frozen.is_file() else scene_path(scene)

    paths = [path(s) for s in scenes] if scenes else sorted(FROZEN.glob("*.yaml"))
    out = ROOT / "data" / "bench" / "frozen"
    return [ensure_simulation(p, 0, out / f"{p.stem}-goals8-seed0.mcap", goals=8) for p in paths]


def _run(dataset: Path, store: Path, sets: list[str]) -> dict[str, Any]:
    sets = ["keyframes.spacing_m=4", "slam.mode=ground_truth", *sets]
    cmd = [sys.executable, "-m", "sonarmap.pipeline", "run", str(dataset), "--store", str(store)]
    cmd += ["--json", "-q", *(a for s in sets for a in ("--set", s))]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"{dataset}: sonarmap run failed: {proc.stderr.strip().splitlines()[-1]}")
    return json.loads(proc.stdout)


def _confusion(result: dict[str, Any]) -> dict[str, dict[str, int]]:
    import pyarrow.parquet as pq

    classify = next(s for s in result["stages"] if s["stage"] == "classify")
    table = pq.read_table(Path(classify["path"]) / "objects.parquet")
    pairs = Counter(
        zip(
            table.column("true_class_name").to_pylist(),
            table.column("class_name").to_pylist(),
            strict=True,
        )
    )
    out: dict[str, dict[str, int]] = {}
    for (truth, assigned), n in sorted(
        pairs.items(), key=lambda kv: (str(kv[0][0]), str(kv[0][1]))
    ):
        out.setdefault(str(truth), {})[str(assigned)] = n
    return out


def _ratio(num: float | None, den: float | None) -> float | None:
    return num / den if num is not None and den else None


def _figures(result: dict[str, Any]) -> dict[str, Any]:
    per_class = result["summary"]["metrics"]["per_class"]
    classes = per_class["classes"]
    whole = classes["all_structure"]
    inferred_m = (whole.get("inferred") or {}).get("median_error_m")
    gains = {
        name: _ratio(c["semantic"]["accurate_voxels"], c["standard"]["accurate_voxels"])
        for name, c in classes.items()
        if name != "all_structure"
    }
    return {
        "accurate": _ratio(
            whole["semantic"]["accurate_voxels"], whole["standard"]["accurate_voxels"]
        ),
        "error_ratio": _ratio(inferred_m, whole["standard"]["median_error_m"]),
        "gain_by_class": gains,
        "inferred_over_fused_by_class": {
            name: c["inferred_over_fused"]
            for name, c in per_class["assigned_classes"].items()
            if c.get("inferred_over_fused") is not None
        },
        "confusion": _confusion(result),
    }


def _mark(key: str, value: float | None) -> str:
    if value is None:
        return "-"
    ok = value >= GOALS[key] if key == "accurate" else value <= GOALS[key]
    return f"{value:.2f}" + ("" if ok else " ✗")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "scenes", nargs="*", help="scene names or files (default: configs/scenes/frozen)"
    )
    ap.add_argument("--store", default=str(ROOT / "data" / "store"))
    ap.add_argument("--set", dest="sets", action="append", default=[], help="section.field=value")
    ap.add_argument("--labels", default="cnn,oracle", help="labellings to run: cnn and/or oracle")
    args = ap.parse_args()
    rows = []
    for dataset in _recordings(args.scenes):
        for labelling in args.labels.split(","):
            sets = LABELLINGS[labelling]
            result = _run(dataset, Path(args.store), [*sets, *args.sets])
            rows.append({"dataset": dataset.name, "labels": labelling, **_figures(result)})
    print(json.dumps({"goals": GOALS, "overrides": args.sets, "rows": rows}, indent=2))
    print("| dataset | labels | accurate (≥ 5x) | inferred/fused (≤ 1.2x) | gain by class |",
          file=sys.stderr)  # fmt: skip
    for r in rows:
        gains = ", ".join(f"{k} {v:.1f}" for k, v in r["gain_by_class"].items() if v is not None)
        cells = f"{_mark('accurate', r['accurate'])} | {_mark('error_ratio', r['error_ratio'])}"
        print(f"| {r['dataset']} | {r['labels']} | {cells} | {gains} |", file=sys.stderr)
    print("\nCNN confusion (true -> assigned: objects)", file=sys.stderr)
    for r in rows:
        if r["labels"] == "cnn":
            for truth, row in r["confusion"].items():
                cells = ", ".join(f"{k} {n}" for k, n in row.items())
                print(f"  {r['dataset']}: {truth} -> {cells}", file=sys.stderr)


if __name__ == "__main__":
    main()
