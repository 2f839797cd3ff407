"""Scores computed from artifacts for run summaries (no algorithms, only counting)."""

from __future__ import annotations

from typing import Any

import pyarrow as pa

from sonarmap.schemas.classes import PILING_CLASSES, UNKNOWN_CLASS

__all__ = ["classification_scores"]

NO_STRUCTURE = "none"
"""The label of an object on no true structure (class id 0 of every table)."""


def classification_scores(objects: pa.Table) -> dict[str, Any]:
    """Per-class precision (among accepted predictions) and recall, when labels exist.

    Returns {"objects": n, "accepted": n, "per_class": {name: {"precision", "recall",
    "support"}}, "piling_recall": r, "piling_precision": p}; "none"'s recall is the share
    of the objects on no structure that nothing is claimed for. Only counts when
    `true_class_name` is present and labels at least one object: an unlabelled recording
    has no precision to report, not a precision of zero.
    """
    import numpy as np  # not at import: a cached run's summary loads no numpy

    n = objects.num_rows
    result: dict[str, Any] = {"objects": n}
    if n == 0 or "true_class_name" not in objects.column_names:
        return result
    predicted = np.asarray(objects.column("class_name").to_pylist(), dtype=object)
    truth = np.asarray(objects.column("true_class_name").to_pylist(), dtype=object)
    if not any(truth):
        return result
    result["accepted"] = int((predicted != UNKNOWN_CLASS).sum())
    per_class: dict[str, Any] = {}
    for name in sorted({t for t in truth if t} | {p for p in predicted if p != UNKNOWN_CLASS}):
        called, true = predicted == name, truth == name
        # An object on no structure is recalled when nothing is claimed for it: left
        # unknown is the right answer for clutter, as calling it none is.
        recalled = called | (predicted == UNKNOWN_CLASS) if name == NO_STRUCTURE else called
        pred, support = int(called.sum()), int(true.sum())
        per_class[name] = {
            "precision": int((called & true).sum()) / pred if pred else None,
            "recall": int((recalled & true).sum()) / support if support else None,
            "support": support,
        }
    result["per_class"] = per_class
    piling_true = np.isin(truth, list(PILING_CLASSES))
    piling_hit = int((piling_true & (predicted == truth)).sum())
    result["piling_recall"] = piling_hit / int(piling_true.sum()) if piling_true.any() else None
    # Precision the same way: of the objects called a piling class, the share that are that
    # class (an object called a piling but of another class, or of none, is a false one).
    piling_called = int(np.isin(predicted, list(PILING_CLASSES)).sum())
    result["piling_precision"] = piling_hit / piling_called if piling_called else None
    return result
