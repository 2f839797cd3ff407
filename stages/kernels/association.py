"""Orthogonal stereo association per range bin (paper Sec. IV.B, Eq. 5 and 6).

Per frame, after the overlap selection of `sonarmap.stages.kernels.fusion`:
1. Subproblems: features in the same range bin of both images (paper: "features at the
   same range"; the vertical features' ranges are binned with the horizontal sonar's
   range table, so the two images may differ in resolution); each is solved optimally (minimum total cost) with
   `scipy.optimize.linear_sum_assignment` over the cost of Eq. 5,
       L(z_h, z_v) = || nu_h - rot90(nu_v) ||_F,
   nu = square patch (5x5 by default) around the feature in the image normalised per
   keyframe (level / image maximum), the vertical patch rotated 90 deg clockwise.
2. Confidence, Eq. 6, per association (i, j) of the solution: C = (L_2 - L_ij) / sum L,
   L_2 = the cheapest alternative of either feature (row i without j, column j without i),
   sum L = the sum of the costs of those candidates and L_ij. C < 0 when the solution had
   to give a feature a worse partner than its best; C = 1 when neither feature had an
   alternative. Associations with C < `min_confidence` are culled. The default (-1) culls
   none, because on the simulator C does not predict 3D accuracy
   (docs/decisions/006-fuse-keeps-every-association.md).
   Options after the authors' code (docs/authors-code.md Sec. 3.1 steps
   8-9), all off by default:
   - `min_subproblem_features`: a range bin is solved only when both its horizontal and
     its vertical set hold at least this many features (the original: more than 2);
     the features of smaller subproblems are never associated.
   - `confidence_rule="ratio"`: a deterministic analogue of the original's per-feature
     cost ratio. The original drew |L| random pairings of a subproblem (L the larger
     set, S the smaller) and took, per feature of S, the smallest over the second-smallest
     of the costs it was paired with; here every candidate is enumerated and an
     association (i, j) of the optimal solution gets rho = L_ij / L_2, L_2 = the cheapest
     other candidate of its feature in S: the horizontal one when the bin has fewer
     horizontal than vertical features, else (fewer vertical, or as many: the original
     does not say, the authors' later C++ matcher rates the vertical features) the
     vertical one. When the solution gives that feature its cheapest partner, rho is the
     original's smallest / second-smallest; otherwise rho >= 1 (the original still rated
     the feature by its best sampled cost, kept or not: here it is culled by any cut
     < 1). No alternative (a 1 x 1 subproblem): rho = 0, as Eq. 6 gives C = 1 there;
     0 / 0: rho = 1. The `confidence` column then holds C = (1 - rho) / (1 + rho) =
     (L_2 - L_ij) / (L_2 + L_ij), in [-1, 1] and decreasing in rho (rho = (1 - C) /
     (1 + C)); `min_confidence` still culls on it.
   - `max_cost_ratio`: with the ratio rule, keep only associations with rho below this
     (the original kept rows with ratio < 0.97 in simulation, 0.98 on real data), i.e.
     C > (1 - max) / (1 + max).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sonarmap.stages.kernels.choices import ConfidenceRule
from sonarmap.stages.kernels.lazy import lazy

optimize = lazy("scipy.optimize")

__all__ = ["ConfidenceRule", "assign_subproblems", "image_patches"]


def image_patches(image: np.ndarray, rows: np.ndarray, cols: np.ndarray, size: int) -> np.ndarray:
    """Square patches around cells of an image normalised to its maximum (zero-padded).

    Args:
        image: (n_ranges, n_beams) polar image.
        rows, cols: (n,) cell indices.
        size: odd patch side [pixels].

    Returns:
        (n, size, size) float32 patches in [0, 1], patch row = range, column = beam.
    """
    if size % 2 == 0:
        raise ValueError(f"patch size must be odd, got {size}")
    h = size // 2
    img = np.asarray(image)
    peak = float(img.max()) if img.size else 0.0
    d = np.arange(size)
    padded = np.pad(img, h)
    patches = padded[rows[:, None, None] + d[None, :, None], cols[:, None, None] + d[None, None, :]]
    return patches.astype(np.float32) / np.float32(peak if peak > 0 else 1.0)


def _same_bin_pairs(bin_h: np.ndarray, bin_v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All (i, j) with bin_h[i] == bin_v[j], grouped by bin, row-major within a bin.

    Both inputs must be sorted ascending. Returns (m,) int64 index arrays.
    """
    lo = np.searchsorted(bin_v, bin_h, side="left")
    n = np.searchsorted(bin_v, bin_h, side="right") - lo
    i = np.repeat(np.arange(len(bin_h)), n)
    first = np.repeat(np.cumsum(n) - n, n)
    j = lo[i] + (np.arange(len(i)) - first)
    return i.astype(np.int64), j.astype(np.int64)


def _confidence(
    i: np.ndarray,
    j: np.ndarray,
    cost: np.ndarray,
    chosen: np.ndarray,
    nh: int,
    nv: int,
    rule: ConfidenceRule = "paper",
) -> np.ndarray:
    """Confidence of the chosen candidate pairs (vectorised over all subproblems).

    Args:
        i, j, cost: (m,) all candidate pairs and their costs.
        chosen: (k,) indices into the candidates of the assigned pairs.
        nh, nv: numbers of horizontal / vertical features.
        rule: "paper" (Eq. 6) or "ratio" (module docstring).

    Returns:
        (k,) "paper": (L_2 - L_ij) / sum L, L_2 = cheapest alternative of either feature,
        sum over both features' candidates (the pair once); "ratio": (L_2 - L_ij) / (L_2 +
        L_ij) = (1 - rho) / (1 + rho), rho = L_ij / L_2, L_2 = cheapest alternative of
        the feature in the bin's smaller set (the vertical one if equal; C = 0, rho = 1,
        where both costs are 0). Both are 1 where there is no alternative.
    """
    others = np.ones(len(cost), dtype=bool)
    others[chosen] = False
    alt = np.where(others, cost, np.inf)
    row_min = np.full(nh, np.inf)
    col_min = np.full(nv, np.inf)
    np.minimum.at(row_min, i, alt)
    np.minimum.at(col_min, j, alt)
    ci, cj, cc = i[chosen], j[chosen], cost[chosen]
    if rule == "ratio":
        # Row i holds |V| candidates of its bin, column j |H|: rate the smaller set's feature.
        n_v, n_h = np.bincount(i, minlength=nh)[ci], np.bincount(j, minlength=nv)[cj]
        second = np.where(n_h < n_v, row_min[ci], col_min[cj])
        pair = np.where(np.isfinite(second), second + cc, 1.0)
        conf = np.where(pair > 0, (second - cc) / np.maximum(pair, 1e-300), 0.0)
        return np.where(np.isfinite(second), conf, 1.0)
    second = np.minimum(row_min[ci], col_min[cj])
    row_sum = np.bincount(i, weights=cost, minlength=nh)
    col_sum = np.bincount(j, weights=cost, minlength=nv)
    total = row_sum[ci] + col_sum[cj] - cc
    conf = np.where(total > 0, (second - cc) / np.maximum(total, 1e-12), 0.0)
    return np.where(np.isfinite(second), conf, 1.0)


def assign_subproblems(
    bin_h: np.ndarray,
    bin_v: np.ndarray,
    cost_fn: Any,
    *,
    min_features: int = 1,
    confidence_rule: ConfidenceRule = "paper",
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Minimum-cost assignment per range bin (Eq. 5) with Eq. 6 (or ratio) confidences.

    Args:
        bin_h, bin_v: (nh,), (nv,) sorted range bins of the horizontal / vertical features.
        cost_fn: cost_fn(i, j) -> (m,) costs of candidate pairs (index arrays).
        min_features: a bin is solved only if both of its sets hold at least this many
            features (the original code's gate: 3); the others are left unassigned.
        confidence_rule: "paper" (Eq. 6) or "ratio" (see `_confidence`).

    Returns:
        i, j (k,) int64 assigned feature indices (by bin, then i), cost (k,), confidence (k,).
    """
    i, j = _same_bin_pairs(bin_h, bin_v)
    if min_features > 1 and len(i):
        b = bin_h[i]
        n_h = np.searchsorted(bin_h, b, "right") - np.searchsorted(bin_h, b, "left")
        n_v = np.searchsorted(bin_v, b, "right") - np.searchsorted(bin_v, b, "left")
        used = (n_h >= min_features) & (n_v >= min_features)
        i, j = i[used], j[used]
    if len(i) == 0:
        e = np.zeros(0, np.int64)
        return e, e, np.zeros(0), np.zeros(0)
    cost = np.asarray(cost_fn(i, j), dtype=np.float64)
    bins = bin_h[i]
    starts = np.flatnonzero(np.r_[True, bins[1:] != bins[:-1]])
    ends = np.r_[starts[1:], len(i)]
    n_v = np.searchsorted(bin_v, bins[starts], "right") - np.searchsorted(bin_v, bins[starts])
    chosen = []
    for s, e, nv in zip(starts.tolist(), ends.tolist(), n_v.tolist(), strict=True):
        r, c = optimize.linear_sum_assignment(cost[s:e].reshape(-1, nv))
        chosen.append(s + r * nv + c)
    sel = np.concatenate(chosen)
    conf = _confidence(i, j, cost, sel, len(bin_h), len(bin_v), confidence_rule)
    return i[sel], j[sel], cost[sel], conf
