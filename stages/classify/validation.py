"""Validation of a trained classifier: MC-dropout metrics per class and the confusion-matrix figure."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.stages.kernels.figure_png import png_bytes
from sonarmap.stages.kernels.lazy import lazy

if TYPE_CHECKING:
    from sonarmap.stages.classify.cnn import PatchCNN

cnn = lazy("sonarmap.stages.classify.cnn")

__all__ = ["McSettings", "confusion_png", "evaluate", "say_what_is_not_learned"]

log = logging.getLogger(__name__)


class McSettings(Protocol):
    """What the validation reads of the training config (`TrainConfig` has them)."""

    mc_passes: int
    seed: int
    threshold: float


def evaluate(
    model: PatchCNN, patches: np.ndarray, target: np.ndarray, class_names: Sequence[str],
    cfg: McSettings,
) -> dict[str, Any]:  # fmt: skip
    """Validation metrics with MC dropout (m = cfg.mc_passes, seeded).

    Returns:
        {"n": int, "accuracy": float, "confusion": [[int]] (rows = true, cols = argmax),
        "classes": {name: {"support", "precision", "recall", "accepted",
        "accepted_precision", "accepted_recall"}}, "accepted_fraction": float,
        "threshold": float}; a ratio with an empty denominator is None. "accepted" = mean
        probability > threshold.
    """
    k = len(class_names)
    mean, _ = cnn.mc_predict(model, patches, cfg.mc_passes, cfg.seed)
    pred = mean.argmax(axis=1) if len(mean) else np.zeros(0, np.int64)
    acc = mean.max(axis=1) > cfg.threshold if len(mean) else np.zeros(0, bool)
    cm = np.bincount(target * k + pred, minlength=k * k).reshape(k, k)
    cm_acc = np.bincount(target[acc] * k + pred[acc], minlength=k * k).reshape(k, k)

    def ratio(a: float, b: float) -> float | None:
        return float(a / b) if b > 0 else None

    classes = {
        name: {
            "support": int(cm[i].sum()),
            "precision": ratio(cm[i, i], cm[:, i].sum()),
            "recall": ratio(cm[i, i], cm[i].sum()),
            "accepted": int(cm_acc[:, i].sum()),
            "accepted_precision": ratio(cm_acc[i, i], cm_acc[:, i].sum()),
            "accepted_recall": ratio(cm_acc[i, i], cm[i].sum()),
        }
        for i, name in enumerate(class_names)
    }
    n = len(target)
    return {
        "n": n,
        "accuracy": ratio(np.trace(cm), n),
        "accepted_fraction": ratio(acc.sum(), n),
        "threshold": float(cfg.threshold),
        "confusion": cm.tolist(),
        "class_names": list(class_names),
        "classes": classes,
    }


def confusion_png(confusion: Sequence[Sequence[int]], class_names: Sequence[str]) -> bytes:
    """Confusion matrix (rows = true, columns = predicted) as PNG bytes."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    cm = np.asarray(confusion, dtype=np.int64).reshape(len(class_names), len(class_names))
    fig = Figure(figsize=(1.2 * len(class_names) + 2, 1.0 * len(class_names) + 1.5), dpi=100)
    ax = fig.add_subplot()
    ax.imshow(cm / np.maximum(cm.sum(axis=1, keepdims=True), 1), cmap="Blues", vmin=0, vmax=1)
    for (i, j), v in np.ndenumerate(cm):
        ax.text(j, i, str(v), ha="center", va="center", fontsize=8)
    ax.set_xticks(range(len(class_names)), class_names, rotation=45, ha="right", fontsize=8)
    ax.set_yticks(range(len(class_names)), class_names, fontsize=8)
    ax.set_xlabel("predicted (argmax of MC mean)")
    ax.set_ylabel("true (label image)")
    fig.tight_layout()
    return png_bytes(fig)


def say_what_is_not_learned(
    class_id: np.ndarray, train: np.ndarray, val: np.ndarray, ids: list[int], min_samples: int,
    table: ClassTable = DEFAULT_TABLE,
) -> list[str]:  # fmt: skip
    """Warnings for each labelled class left out for too few objects, and for a model with
    nothing to validate on: neither is ever silent. Each is logged and returned (the
    model's metrics keep them, so a cached model says them again)."""
    said = []
    counts = np.bincount(class_id[train], minlength=len(table.names_by_id()))
    for entry in table.table:
        if entry.frame_kind != "none" and counts[entry.id] == 0:
            said.append(
                f"class {entry.name}: no labelled training object: the model will not know it"
            )
    for c in np.flatnonzero(counts > 0):
        if c != 0 and int(c) not in ids:
            said.append(
                f"class {table.name_of(int(c))}: {counts[c]} training objects, under"
                f" train.min_class_samples={min_samples}: not learned"
            )
    if not np.isin(class_id[val], ids).any():
        said.append(
            f"no validation object of a learned class ({int(val.sum())} held out in all): the"
            " model's figures are empty and it is unvalidated; label more keyframes across the"
            " recording (validation holds out blocks of keyframe time)"
        )
    for line in said:
        log.warning("%s", line)
    return said
