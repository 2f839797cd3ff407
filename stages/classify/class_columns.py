"""The class columns of objects.parquet: the classifier's decision, or the oracle's."""

from __future__ import annotations

from typing import Any

import numpy as np

from sonarmap.schemas.classes import UNKNOWN_CLASS, ClassTable
from sonarmap.schemas.objects import UNKNOWN_CLASS_ID

__all__ = ["class_columns", "truth_columns"]


def class_columns(
    pooled: np.ndarray, single: np.ndarray, var: np.ndarray, n_views: np.ndarray,
    class_ids: np.ndarray, names: list[str], threshold: float, min_views: int = 1,
    seen_share: np.ndarray | None = None, min_seen_share: float = 0.0,
    compact: np.ndarray | None = None,
) -> dict[str, Any]:  # fmt: skip
    """The class columns: argmax of the (pooled) mean, accepted above the threshold; a
    compact class (`compact[c]`: an object frame, a piling) only where at least
    `min_views` sightings of its place were pooled and it was sighted by at least
    `min_seen_share` of the keyframes whose fan covered it (`seen_share`; None: not known,
    no such rule). An extended structure (a wall) is not held to them: its clusters'
    centroids move along it with the viewpoint, so its sightings need not fall on one
    place."""
    k = len(pooled)
    best = pooled.argmax(axis=1) if k else np.zeros(0, np.int64)
    rows = np.arange(k)
    p = pooled[rows, best]
    held = np.zeros(len(names), bool) if compact is None else np.asarray(compact, bool)
    seen = np.ones(k) if seen_share is None else np.asarray(seen_share, np.float64)
    confirmed = (n_views >= min_views) & (seen >= min_seen_share)
    accepted = (p > threshold) & (confirmed | ~held[best])
    argmax_names = [names[i] for i in best]
    return {
        "class_id": np.where(accepted, class_ids[best], UNKNOWN_CLASS_ID).astype(np.int64),
        "class_name": [n if a else UNKNOWN_CLASS for n, a in zip(argmax_names, accepted, strict=True)],
        "argmax_class_name": argmax_names,
        "probability": p.astype(np.float64),
        "probability_var": var[rows, best].astype(np.float64),
        "single_view_probability": single[rows, best].astype(np.float64),
        "n_views": n_views.astype(np.int64),
    }  # fmt: skip


def truth_columns(
    truth: np.ndarray, structure_classes: list[str], table: ClassTable
) -> dict[str, Any]:
    """The class columns of the oracle (`labels="ground_truth"`): each object's majority
    label-image class, certain; ids outside `structure_classes` become unknown."""
    names = [table.name_of(int(c)) for c in truth]
    known = np.array([n in structure_classes for n in names], bool)
    k = len(names)
    labels = [n if a else UNKNOWN_CLASS for n, a in zip(names, known, strict=True)]
    return {
        "class_id": np.where(known, truth, UNKNOWN_CLASS_ID).astype(np.int64),
        "class_name": labels,
        "argmax_class_name": list(labels),
        "probability": np.ones(k),
        "probability_var": np.zeros(k),
        "single_view_probability": np.ones(k),
        "n_views": np.ones(k, np.int64),
    }
