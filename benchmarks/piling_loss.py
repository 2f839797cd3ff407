"""Where a run's pilings are lost (issue 50): detection, the CNN's argmax, or its acceptance.

    .venv/bin/python -m benchmarks.piling_loss STORE|OBJECTS.parquet [...] [--json]

For each store (a `sonarmap run --store` of a simulated recording, whose objects carry
their label-image class) it reads the classify stage's `objects.parquet` and prints, for
the objects whose true class is a piling (the recall's denominator,
`sonarmap.pipeline.scoring.classification_scores`):

- how many there are, their cluster size (features) and feature box (median), so
  fragmentation or shrinking under noise shows against the clean sensor;
- how many the CNN's (view-pooled) argmax calls right, how many of those pass the
  acceptance threshold, and how many would at lower thresholds;
- what the wrong argmaxes are, and the piling precision at each threshold (the other half
  of the goal: precision >= 0.95 with recall >= 0.7).

Counting only: nothing is re-run, so it costs seconds.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from sonarmap.schemas.classes import PILING_CLASSES

THRESHOLDS = (0.5, 0.9, 0.95, 0.98, 0.99)
"""0.99 is the shipped acceptance (`classify.threshold`); the rest show what it costs."""


def objects_of(store: Path) -> dict[str, np.ndarray]:
    """The classify stage's objects.parquet of a store holding one run (or that file)."""
    found = [store] if store.is_file() else sorted(store.glob("classify/*/objects.parquet"))
    if len(found) != 1:
        raise SystemExit(f"{store}: expected one classify/*/objects.parquet, found {len(found)}")
    return {k: np.asarray(v) for k, v in pq.read_table(found[0]).to_pydict().items()}


def losses(t: dict[str, np.ndarray]) -> dict[str, Any]:
    """The piling objects' fate in one run's objects table."""
    truth = np.asarray([str(x) for x in t["true_class_name"]])
    argmax = t["argmax_class_name"].astype(str)
    p = t["probability"]
    pile = np.isin(truth, PILING_CLASSES)
    right = pile & (argmax == truth)
    side = np.maximum(t["x_max_m"] - t["x_min_m"], t["y_max_m"] - t["y_min_m"])
    called = np.isin(argmax, PILING_CLASSES)
    n = int(pile.sum())

    def precision(q: float) -> float | None:
        c = called & (p > q)
        return round(float((c & (argmax == truth)).sum() / c.sum()), 3) if c.any() else None

    def recall(q: float) -> float | None:
        return round(float((right & (p > q)).sum() / n), 3) if n else None

    return {
        "objects": len(truth),
        "true_classes": dict(Counter(truth.tolist()).most_common()),
        "pilings": n,
        "piling_features_median": float(np.median(t["n_features"][pile])) if n else None,
        "piling_box_m_median": round(float(np.median(side[pile])), 2) if n else None,
        "argmax_right": int(right.sum()),
        "argmax_of_pilings": dict(Counter(argmax[pile].tolist()).most_common()),
        "right_above": {str(q): int((right & (p > q)).sum()) for q in THRESHOLDS},
        "recall_above": {str(q): recall(q) for q in THRESHOLDS},
        "precision_above": {str(q): precision(q) for q in THRESHOLDS},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stores", nargs="+", type=Path)
    ap.add_argument("--json", action="store_true", help="one JSON document on stdout")
    args = ap.parse_args()
    rows = {str(s): losses(objects_of(s)) for s in args.stores}
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    qs = " ".join(f"p>{q}" for q in THRESHOLDS)
    print(f"| run | pilings | features | box m | argmax right | right and {qs} |"
          " precision at the same |", file=sys.stderr)  # fmt: skip
    for name, r in rows.items():
        above = " / ".join(str(v) for v in r["right_above"].values())
        prec = " / ".join("-" if v is None else f"{v:.2f}" for v in r["precision_above"].values())
        print(
            f"| {name} | {r['pilings']} | {r['piling_features_median']} |"
            f" {r['piling_box_m_median']} | {r['argmax_right']} | {above} | {prec} |",
            file=sys.stderr,
        )
        print(f"  argmax of the pilings: {r['argmax_of_pilings']}", file=sys.stderr)


if __name__ == "__main__":
    main()
