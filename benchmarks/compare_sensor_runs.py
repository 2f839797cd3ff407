"""Two `bench_sensors` JSON documents side by side: how many rows meet each of issue 50's
per-row goals with each, the sum of piling F1, and every row's figures (a model or
front-end change against the shipped one).

    .venv/bin/python -m benchmarks.bench_sensors ... > before.json
    .venv/bin/python -m benchmarks.bench_sensors ... --set classify.model=DIR > after.json
    .venv/bin/python benchmarks/compare_sensor_runs.py before.json after.json
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

Row = dict[str, Any]

GOALS: dict[str, Callable[[Row], bool]] = {
    "standard error <= 0.12 m": lambda r: r["standard_m"] <= 0.12,
    "semantic / standard <= 1.2": lambda r: r["semantic_over_standard"] <= 1.2,
    "accurate voxels >= 4x": lambda r: r["accurate_ratio"] >= 4,
    ">= 0.7x the clean sensor's": lambda r: r["semantic_over_clean"] >= 0.7,
    "piling precision >= 0.95": lambda r: (r["piling_precision"] or 0.0) >= 0.95,
    "piling recall >= 0.7": lambda r: (r["piling_recall"] or 0.0) >= 0.7,
}


def piling_f1(row: Row) -> float:
    p, r = row["piling_precision"] or 0.0, row["piling_recall"] or 0.0
    return 0.0 if p + r == 0 else 2 * p * r / (p + r)


def _rows(path: Path) -> dict[tuple[str, str], Row]:
    return {(r["scene"], r["sensor"]): r for r in json.loads(path.read_text())["rows"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("before", type=Path)
    parser.add_argument("after", type=Path)
    args = parser.parse_args()
    before, after = _rows(args.before), _rows(args.after)
    common = [k for k in before if k in after]
    print(f"rows in both: {len(common)}")
    print("| goal | before | after |\n|---|---:|---:|")
    for name, met in GOALS.items():
        print(f"| {name} | {sum(met(before[k]) for k in common)} | {sum(met(after[k]) for k in common)} |")
    f1_before = sum(piling_f1(before[k]) for k in common)
    f1_after = sum(piling_f1(after[k]) for k in common)
    print(f"| sum of piling F1 | {f1_before:.2f} | {f1_after:.2f} |")
    for k in common:
        b, a = before[k], after[k]
        print(
            f"{k[0][:14]:14s} {k[1]:12s} piling P/R {b['piling_precision'] or 0:.2f}/"
            f"{b['piling_recall'] or 0:.2f} -> {a['piling_precision'] or 0:.2f}/"
            f"{a['piling_recall'] or 0:.2f}  accurate {b['accurate_ratio']:.2f}x -> "
            f"{a['accurate_ratio']:.2f}x  vs clean {b['semantic_over_clean']:.2f} -> "
            f"{a['semantic_over_clean']:.2f}  sem/std {b['semantic_over_standard']:.2f} -> "
            f"{a['semantic_over_standard']:.2f}"
        )


if __name__ == "__main__":
    main()
