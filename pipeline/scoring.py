"""Scores computed from artifacts for run summaries (no algorithms, only counting)."""

from __future__ import annotations

from typing import Any

import pyarrow as pa

from sonarmap.schemas.classes import PILING_CLASSES, UNKNOWN_CLASS

__all__ = ["classification_scores"]


def classification_scores(objects: pa.Table) -> dict[str, Any]:
    """Per-class precision (among accepted predictions) and recall, when labels exist.

    Returns {"objects": n, "accepted": n, "per_class": {name: {"precision", "recall",
    "support"}}, "piling_recall": r, "piling_precision": p}; only counts when `true_class_name` is present
    and labels at least one object: an unlabelled recording has no precision to report,
    not a precision of zero.
    """
    n = objects.num_rows
    result: dict[str, Any] = {"objects": n}
    if n == 0 or "true_class_name" not in objects.column_names:
        return result
    predicted = objects.column("class_name").to_pylist()
    truth = objects.column("true_class_name").to_pylist()
    if not any(truth):
        return result
    accepted = [p != UNKNOWN_CLASS for p in predicted]
    result["accepted"] = int(sum(accepted))
    per_class: dict[str, Any] = {}
    for name in sorted({t for t in truth if t} | {p for p in predicted if p != UNKNOWN_CLASS}):
        tp = sum(1 for p, t in zip(predicted, truth, strict=True) if p == name and t == name)
        pred = sum(1 for p in predicted if p == name)
        support = sum(1 for t in truth if t == name)
        per_class[name] = {
            "precision": tp / pred if pred else None,
            "recall": tp / support if support else None,
            "support": support,
        }
    result["per_class"] = per_class
    piling_truth = sum(1 for t in truth if t in PILING_CLASSES)
    piling_hit = sum(
        1 for p, t in zip(predicted, truth, strict=True) if t in PILING_CLASSES and p == t
    )
    result["piling_recall"] = piling_hit / piling_truth if piling_truth else None
    # Precision the same way: of the objects called a piling class, the share that are that
    # class (an object called a piling but of another class, or of none, is a false one).
    piling_called = sum(1 for p in predicted if p in PILING_CLASSES)
    result["piling_precision"] = piling_hit / piling_called if piling_called else None
    return result
