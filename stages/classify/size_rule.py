"""The training set's size by a stated rule (issue 39, item 4): add worlds until the
held-out validation stops improving.

Training datasets (worlds) are added in their order, doubling from `grow_step_datasets`; each
size trains a model from scratch with the same recipe and scores it on the held-out
datasets (whole worlds never trained on) by macro-F1 (argmax of the MC-dropout mean, over
the learned classes with validation support). A size counts as an improvement when its
macro-F1 beats the best so far by at least `grow_min_gain_f1`; after `grow_patience`
sizes in a row without one, growing stops. The chosen size is the best one: the
smallest set after which adding worlds stopped paying.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from sonarmap.stages.kernels.figure_png import png_bytes

if TYPE_CHECKING:
    from sonarmap.stages.classify.cnn import PatchCNN

__all__ = ["GrowSettings", "curve_png", "grow", "macro_f1", "one_size", "sizes"]

log = logging.getLogger(__name__)


class GrowSettings(Protocol):
    """What the rule reads of the training config (`TrainConfig` has them)."""

    grow_step_datasets: int
    grow_min_gain_f1: float
    grow_patience: int


def macro_f1(confusion: Sequence[Sequence[int]]) -> float:
    """Mean F1 over the classes with validation support (rows = true, cols = predicted)."""
    cm = np.asarray(confusion, dtype=np.float64)
    tp = np.diag(cm)
    support, predicted = cm.sum(axis=1), cm.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        f1 = np.where(support + predicted > 0, 2 * tp / (support + predicted), 0.0)
    return float(f1[support > 0].mean()) if (support > 0).any() else 0.0


def sizes(n_datasets: int, step: int) -> list[int]:
    """Training-set sizes tried, in order: step, 2 step, 4 step, ... (doubling: each size
    costs a training from scratch, and a gain shows on a doubling if anywhere), and always
    n_datasets."""
    out = {n_datasets}
    size = step
    while size < n_datasets:
        out.add(size)
        size *= 2
    return sorted(out)


def grow(
    dataset: np.ndarray,
    train: np.ndarray,
    n_datasets: int,
    fit: Callable[[np.ndarray], PatchCNN],
    score: Callable[[PatchCNN], dict[str, Any]],
    cfg: GrowSettings,
) -> tuple[PatchCNN, dict[str, Any]]:
    """Apply the rule.

    Args:
        dataset: (n,) dataset index of every sample.
        train: (n,) samples that may train (held-out worlds and unlearned classes not).
        n_datasets: training datasets (indices 0..n_datasets-1, added in that order).
        fit: trains a model on the samples of a mask.
        score: validation metrics of a model (`sonarmap.stages.classify.validation.evaluate`).

    Returns:
        The model of the chosen size and the curve: {"rule", "points": [{"datasets",
        "objects", "macro_f1"}], "chosen_datasets", "converged"}.
    """
    points: list[dict[str, Any]] = []
    best: tuple[float, int, PatchCNN] | None = None
    misses = 0
    for size in sizes(n_datasets, cfg.grow_step_datasets):
        mask = train & (dataset < size)
        model = fit(mask)
        f1 = macro_f1(score(model)["confusion"])
        points.append({"datasets": size, "objects": int(mask.sum()), "macro_f1": round(f1, 4)})
        log.info("size rule: %d datasets, %d objects: held-out macro-F1 %.4f", size, mask.sum(), f1)
        if best is None or f1 >= best[0] + cfg.grow_min_gain_f1:
            best, misses = (f1, size, model), 0
        else:
            misses += 1
            if misses >= cfg.grow_patience:
                break
    assert best is not None
    converged = misses >= cfg.grow_patience
    if not converged:
        log.warning(
            "size rule: the sizes ran out before %d in a row without a gain (best: %d of %d"
            " datasets); more worlds may help (training.procedural.worlds)",
            cfg.grow_patience,
            best[1],
            n_datasets,
        )
    curve = {
        "rule": f"double the datasets from {cfg.grow_step_datasets}; stop after"
        f" {cfg.grow_patience} sizes in a row that beat the best held-out macro-F1 by less"
        f" than {cfg.grow_min_gain_f1}; keep the best",
        "points": points,
        "chosen_datasets": best[1],
        "converged": converged,
    }
    return best[2], curve


def one_size(n_datasets: int, objects: int, confusion: Sequence[Sequence[int]]) -> dict[str, Any]:
    """The curve of a model trained without held-out datasets: its one size."""
    f1 = round(macro_f1(confusion), 4)
    return {
        "rule": "none (no held-out datasets: validated on held-out keyframe blocks)",
        "points": [{"datasets": n_datasets, "objects": objects, "macro_f1": f1}],
        "chosen_datasets": n_datasets,
        "converged": False,
    }


def curve_png(curve: dict[str, Any]) -> bytes:
    """The held-out macro-F1 against the training-set size, the chosen size marked."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    pts = curve["points"]
    x = [p["datasets"] for p in pts]
    y = [p["macro_f1"] for p in pts]
    fig = Figure(figsize=(5, 3.2), dpi=100)
    ax = fig.add_subplot()
    ax.plot(x, y, "o-", color="tab:blue")
    chosen = curve["chosen_datasets"]
    ax.plot([chosen], [y[x.index(chosen)]], "s", color="tab:red", label=f"chosen: {chosen}")
    ax.set_xlabel("training datasets (worlds)")
    ax.set_ylabel("held-out macro-F1")
    ax.set_title("training-set size (held out by world)", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return png_bytes(fig)
