"""Constant false alarm rate (CFAR) detection along range, per beam, on a polar sonar image.

Paper Sec. IV.C: smallest-of cell-averaging CFAR (SOCA-CFAR, Richards 2005), the detector
of the authors' code (docs/authors-code.md section 2.1). For the cell under test
(CUT) at range row i of a beam, with `train_hs` training and `guard_hs` guard cells on
each side along range,

    leading  = sum of rows i - guard_hs - train_hs .. i - guard_hs - 1
    lagging  = sum of rows i + guard_hs + 1 .. i + guard_hs + train_hs
    noise    = min(leading, lagging) / train_hs        (SOCA)
             = (leading + lagging) / (2 train_hs)      (CA)
             = max(leading, lagging) / train_hs        (GO)
             = k-th smallest of the 2 train_hs cells   (OS, rank k)
    detect   = I(i) > tau * noise  and  I(i) > intensity floor.

Rows closer than train_hs + guard_hs to either image edge are never detections (the
authors' rule). The threshold factor tau comes from the desired false-alarm probability
Pfa under the exponential (square-law, white Gaussian noise) model, with N = 2 train_hs:

    CA:   tau = N (Pfa^(-1/N) - 1)
    SOCA: Pfa / 2 = sum_{k=0}^{N/2-1} C(N/2-1+k, k) (2 + tau/(N/2))^-(N/2+k)
    GO:   Pfa / 2 = (1 + tau/(N/2))^-(N/2) - [SOCA sum]
    OS:   Pfa = prod_{i=0}^{k-1} (N - i) / (N - i + tau)

The cell averages come from one box sum along range per image (whole-image vector adds);
the order statistic from a strided window view and `np.partition`.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from sonarmap.stages.kernels.choices import CfarMethod
from sonarmap.stages.kernels.lazy import lazy

optimize = lazy("scipy.optimize")
special = lazy("scipy.special")

__all__ = ["CfarMethod", "cfar_detect", "cfar_detect_rows", "cfar_noise", "threshold_factor"]


def _soca_core(tau: float, half: int) -> float:
    """SOCA sum of the Pfa formula (N/2 = half cells per side)."""
    k = np.arange(half, dtype=np.float64)
    base = 2.0 + tau / half
    log_terms = (
        special.gammaln(half + k)
        - special.gammaln(k + 1)
        - special.gammaln(half)
        - (half + k) * np.log(base)
    )
    return float(np.exp(log_terms).sum())


def _pfa(method: CfarMethod, tau: float, n_train: int, rank: int) -> float:
    """False-alarm probability of threshold factor `tau` (exponential noise model)."""
    half = n_train // 2
    if method == "ca":
        return float((1.0 + tau / n_train) ** (-n_train))
    if method == "soca":
        return 2.0 * _soca_core(tau, half)
    if method == "go":
        return 2.0 * ((1.0 + tau / half) ** (-half) - _soca_core(tau, half))
    i = np.arange(rank, dtype=np.float64)
    return float(np.exp(np.sum(np.log(n_train - i) - np.log(n_train - i + tau))))


@lru_cache(maxsize=64)
def threshold_factor(method: CfarMethod, n_train: int, pfa: float, rank: int = 0) -> float:
    """Threshold factor tau for the desired false-alarm probability (closed form or solve).

    Args:
        method: "soca", "ca", "go" or "os".
        n_train: training cells in total, both sides (even, >= 2).
        pfa: desired probability of false alarm, in (0, 1).
        rank: OS only, 1-based rank k of the order statistic (1 <= k <= n_train).

    Returns:
        tau > 0 such that Pfa(tau) = pfa (section 2.1 formulas; Pfa decreases in tau).

    Raises:
        ValueError: bad arguments, or no tau reaches `pfa` (e.g. GO at very large pfa).
    """
    if n_train < 2 or n_train % 2:
        raise ValueError(f"n_train must be even and >= 2, got {n_train}")
    if not 0.0 < pfa < 1.0:
        raise ValueError(f"pfa must be in (0, 1), got {pfa}")
    if method == "os" and not 1 <= rank <= n_train:
        raise ValueError(f"OS rank must be in 1..{n_train}, got {rank}")
    if method == "ca":
        return float(n_train * (pfa ** (-1.0 / n_train) - 1.0))
    lo, hi = 1e-9, 1.0
    while _pfa(method, hi, n_train, rank) > pfa:
        hi *= 2.0
        if hi > 1e12:
            raise ValueError(f"{method} CFAR cannot reach pfa={pfa} with {n_train} cells")
    if _pfa(method, lo, n_train, rank) < pfa:
        raise ValueError(f"{method} CFAR cannot reach pfa={pfa} with {n_train} cells")
    return float(
        optimize.brentq(lambda t: _pfa(method, t, n_train, rank) - pfa, lo, hi, xtol=1e-10)
    )


def _window_sums(image: np.ndarray, train_hs: int, guard_hs: int) -> tuple[np.ndarray, np.ndarray]:
    """Leading and lagging training sums for rows w .. n-w-1 (w = train_hs + guard_hs).

    One box sum of train_hs consecutive rows, built by train_hs slice additions (a loop
    over window taps, each a whole-image vector add; faster than a cumulative sum, whose
    sequential dependency numpy cannot vectorise). uint8 images are summed exactly in
    uint16 (train_hs <= 257), other integers in int64, floats in float64.
    """
    n_r, w = image.shape[0], train_hs + guard_hs
    if image.dtype == np.uint8 and train_hs <= 257:
        acc: type = np.uint16
    elif np.issubdtype(image.dtype, np.integer):
        acc = np.int64
    else:
        acc = np.float64
    box: np.ndarray = image[: n_r - train_hs + 1].astype(acc)
    for k in range(1, train_hs):
        box += image[k : n_r - train_hs + 1 + k]
    leading = box[: n_r - 2 * w]
    lagging = box[w + guard_hs + 1 : n_r - train_hs + 1]
    return leading, lagging


def cfar_noise(
    image: np.ndarray, train_hs: int, guard_hs: int, method: CfarMethod = "soca", rank: int = 0
) -> np.ndarray:
    """Per-cell noise estimate along axis 0 (range) of a polar image.

    Args:
        image: (n_ranges, n_beams) intensities (any real dtype).
        train_hs: training cells per side along range.
        guard_hs: guard cells per side along range.
        method: "soca" (default), "ca", "go" or "os".
        rank: OS only, 1-based rank among the 2 train_hs training cells.

    Returns:
        (n_ranges, n_beams) float64 noise level; +inf on the border rows where the
        window does not fit (so nothing is detected there).
    """
    img = np.asarray(image)
    n_r, w = img.shape[0], train_hs + guard_hs
    out = np.full(img.shape, np.inf)
    if n_r < 2 * w + 1:
        return out
    if method == "os":
        win = np.lib.stride_tricks.sliding_window_view(img, 2 * w + 1, axis=0)
        cells = np.concatenate([win[..., :train_hs], win[..., w + guard_hs + 1 :]], axis=-1)
        out[w : n_r - w] = np.partition(cells, rank - 1, axis=-1)[..., rank - 1]
        return out
    leading, lagging = _window_sums(img, train_hs, guard_hs)
    if method == "soca":
        out[w : n_r - w] = np.minimum(leading, lagging) / train_hs
    elif method == "go":
        out[w : n_r - w] = np.maximum(leading, lagging) / train_hs
    elif method == "ca":
        out[w : n_r - w] = (leading + lagging) / (2 * train_hs)
    else:
        raise ValueError(f"unknown CFAR method {method!r}")
    return out


def _check_window(train_hs: int, guard_hs: int, method: str) -> None:
    if train_hs < 1 or guard_hs < 0:
        raise ValueError(f"need train_hs >= 1 and guard_hs >= 0, got {train_hs}, {guard_hs}")
    if method not in ("soca", "ca", "go", "os"):
        raise ValueError(f"unknown CFAR method {method!r}")


def cfar_detect(
    image: np.ndarray,
    train_hs: int,
    guard_hs: int,
    pfa: float,
    method: CfarMethod = "soca",
    rank: int = 0,
    floor: float = 0.0,
) -> np.ndarray:
    """CFAR detections along range, per beam, plus an intensity floor.

    Args:
        image: (n_ranges, n_beams) polar intensities (uint8 levels for sonar images).
        train_hs, guard_hs: training / guard cells per side along range.
        pfa: desired false-alarm probability (sets tau, see `threshold_factor`).
        method: "soca" (default), "ca", "go" or "os".
        rank: OS only, 1-based rank (0 means train_hs, half of the training cells).
        floor: a detection also needs intensity > floor [image levels].

    Returns:
        (n_ranges, n_beams) bool detection mask.
    """
    _check_window(train_hs, guard_hs, method)
    k = (rank or train_hs) if method == "os" else 0
    tau = threshold_factor(method, 2 * train_hs, pfa, k)
    n_r = np.asarray(image).shape[0]
    return cfar_detect_rows(
        image, train_hs, guard_hs, np.full(n_r, tau), np.full(n_r, float(floor)), method, k
    )


def cfar_detect_rows(
    image: np.ndarray,
    train_hs: int,
    guard_hs: int,
    tau_rows: np.ndarray,
    floor_rows: np.ndarray,
    method: CfarMethod = "soca",
    rank: int = 0,
) -> np.ndarray:
    """CFAR detections with a threshold factor and an intensity floor per range row
    (the calibrated front end: `sonarmap.stages.kernels.clutter`, per range band).

    Args:
        image: (n_ranges, n_beams) polar intensities.
        train_hs, guard_hs: training / guard cells per side along range.
        tau_rows: (n_ranges,) threshold factor of each row.
        floor_rows: (n_ranges,) a detection also needs intensity > floor [image levels].
        method: "soca" (default), "ca", "go" or "os".
        rank: OS only, 1-based rank (0 means train_hs).

    Returns:
        (n_ranges, n_beams) bool detection mask.
    """
    _check_window(train_hs, guard_hs, method)
    img = np.asarray(image)
    n_r, w = img.shape[0], train_hs + guard_hs
    mask = np.zeros(img.shape, dtype=bool)
    if n_r < 2 * w + 1:
        return mask
    tau = np.asarray(tau_rows, np.float64)[w : n_r - w, None]
    floor = np.asarray(floor_rows, np.float64)[w : n_r - w, None]
    cut = img[w : n_r - w]
    if method == "os":
        noise = cfar_noise(img, train_hs, guard_hs, method, rank or train_hs)[w : n_r - w]
        mask[w : n_r - w] = (cut > tau * noise) & (cut > floor)
        return mask
    # Fast path: compare sums, no per-cell division (same decision as I > tau * noise).
    leading, lagging = _window_sums(img, train_hs, guard_hs)
    if method == "soca":
        ref, scale = np.minimum(leading, lagging), tau / train_hs
    elif method == "go":
        ref, scale = np.maximum(leading, lagging), tau / train_hs
    else:
        ref, scale = leading + lagging, tau / (2 * train_hs)
    mask[w : n_r - w] = (cut > ref * scale.astype(np.float32)) & (cut > floor)
    return mask
