"""Whether the classifier reads a recording's images consistently: a label-free check.

An object is usually seen from several keyframes, and classify pools its views
(`view_pooling`, a weighted geometric mean of the views' class beliefs). Where the views
agree, pooling makes the CNN surer: more objects clear the acceptance threshold pooled
than in single views. Where they disagree, pooling makes it less sure. Images unlike those
the model learned from (another sensor's grain, gain or noise) make its views of one
object disagree, and the classes it still gives are less reliable.

The rule: warn when fewer objects are accepted pooled than in single views, on at least
`MIN_OBJECTS` objects: the point where pooling takes away more than it adds (its
measurement against piling recall on the benchmark's sensors: docs/classifier.md). The
share of objects the model was sure of on its own validation split is reported beside it
(`validation_sure_fraction`): a recording can differ from the training scenes for many
reasons, so that share is not warned on.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["MIN_OBJECTS", "acceptance_report"]

MIN_OBJECTS = 50
"""Fewer objects say too little about the images to warn on."""


def acceptance_report(
    single_view_max: np.ndarray | None,
    pooled_accepted: int,
    metrics: Mapping[str, Any] | None,
    threshold: float,
) -> dict[str, Any]:
    """The run's shares of sure objects, single-view and pooled, and the warning.

    Args:
        single_view_max: (n,) each object's largest single-view class probability (MC
            mean); None where no CNN ran (labels from ground truth).
        pooled_accepted: objects given a class (pooled probability over `threshold`).
        metrics: the model's `metrics.json` (its validation's `accepted_fraction`).
        threshold: classify's acceptance threshold.

    Returns:
        {"objects", "threshold", "sure_fraction" (single view), "pooled_sure_fraction",
        "validation_sure_fraction", "warnings"}; a share is None without objects.
    """
    metrics = metrics if isinstance(metrics, Mapping) else {}
    n = 0 if single_view_max is None else len(single_view_max)
    single = float(np.mean(single_view_max > threshold)) if n else None
    pooled = pooled_accepted / n if n else None
    warnings = []
    if single is not None and pooled is not None and n >= MIN_OBJECTS and pooled < single:
        warnings.append(
            f"classify: the views of one object disagree: pooled over the keyframes that "
            f"see them, {pooled:.0%} of {n} objects get a class, against {single:.0%} in "
            "single views; these images may not look like those the classifier learned "
            "from (another sensor's grain, gain or noise), so its classes are less "
            "reliable (docs/classifier.md)"
        )
    validation = metrics.get("accepted_fraction")
    return {
        "objects": n,
        "threshold": float(threshold),
        "sure_fraction": None if single is None else round(single, 4),
        "pooled_sure_fraction": None if pooled is None else round(pooled, 4),
        "validation_sure_fraction": validation if isinstance(validation, int | float) else None,
        "validation_threshold": metrics.get("threshold"),
        "warnings": warnings,
    }
