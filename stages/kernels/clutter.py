"""The background (clutter) law of a sonar's images, per range band, and the thresholds it
sets for a stated per-cell false-alarm rate.

Why: a fixed CFAR threshold factor from the exponential (square-law Gaussian) noise model
and a fixed intensity floor flood on bright spiky backgrounds (a real Oculus ping:
median 43 of 255, speckle contrast 0.64) and starve on bright flat ones (ARIS: 89 / 0.28).
Sonar and radar sea clutter is far from exponential; the Weibull law is the usual
two-parameter model of its amplitude (Schleher, "Radar detection in Weibull clutter",
IEEE Trans. AES 12(6), 1976; Abraham & Lyons, "Novel physical interpretations of
K-distributed reverberation", IEEE JOE 27(4), 2002, for sonar), and the background
changes with range (time-varied gain, water column, seabed), so the law is fitted per
range band.

Fit (Weibull-plot regression, robust to the objects): the objects in an image are its
upper tail, so the law is fitted to the bulk only. For a band, with F(v) the empirical
fraction of pixels at or below level v (levels are integers: level v holds the continuous
values in [v - 0.5, v + 0.5); after the 3x3 mean filter, steps of 1/9 level), the points (ln(v + 0.5), ln(-ln(1 - F(v)))) whose F lies in
the central quantiles [q_lo, q_hi] (plus the nearest level outside each end, so that a
coarse, quantised band still has two points) lie on the line k ln x - k ln lambda for a
Weibull law of shape k and scale lambda; least squares gives both (Weibull-plot or
"probability plot" estimation, e.g. Dodson, "The Weibull analysis handbook", ch. 2).

Thresholds, for a stated per-cell false-alarm rate p:
- intensity floor of a band: the smallest integer level L with P(level > L) <= p under the
  fitted law, P(level > L) = exp(-((L + 0.5) / lambda)^k) (the rate actually expected is
  recorded: it is <= p, quantisation makes it lower);
- local CFAR threshold factor: the (1 - pfa_local) quantile of I / noise (noise: the
  SOCA/CA/GO/OS estimate of `sonarmap.stages.kernels.cfar`) over a deterministic Monte Carlo
  image drawn from the fitted law, i.e. tau calibrated for the measured clutter rather than
  from the exponential model's closed form (`cfar.threshold_factor`).

A band is called background (holds no return) when its upper tail is the law's: its sampled
pixels exceed the fitted law's 99.9th percentile (the tail ratio: that share / 0.1 %) at
least as often as the law says (a band whose bulk is a return, the seabed, has a tail
lighter than its law, or clipped at the top level), at most 5x as often, and at most 1.25x
as often as in the sonar's cleanest such band (the law's misfit, common to every band, is
allowed; the excess tail of a band holding returns on 0.1 % of its pixels is not). The
99.9th percentile is the tail point next to the detection rate (1e-3): returns too few to
move the 99th percentile do move it. Detections there are false alarms
(`background_bands`).

Pure numpy (no I/O); `sonarmap.stages.features.calibration` builds the recorded result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sonarmap.stages.kernels.cfar import CfarMethod, cfar_noise

__all__ = [
    "BandLaw",
    "background_bands",
    "band_edges_m",
    "band_histograms",
    "band_of_ranges",
    "exceedance",
    "fit_band",
    "local_threshold_factor",
    "threshold_level",
]

BACKGROUND_TAIL_Q = 0.999
"""A band is background when its pixels exceed the law's 99.9th percentile ..."""
BACKGROUND_TAIL_LIMITS = (1.0, 5.0)
"""... between 1x and 5x as often as the law says (0.1 %) ..."""
BACKGROUND_TAIL_SLACK = 1.25
"""... and at most 1.25x as often as in the cleanest band."""
MIN_SHAPE = 0.5
"""A fitted shape under this is no clutter law (a band mixing two populations)."""
MC_SHAPE = (4096, 32)
"""Rows (range) x beams of the Monte Carlo image that calibrates tau (131 k cells)."""


@dataclass(frozen=True)
class BandLaw:
    """The fitted background of one range band.

    Attributes:
        shape: Weibull shape k (None: the band could not be fitted).
        scale_levels: Weibull scale lambda [image levels].
        median_level: the band's empirical median level.
        pixels: pixels sampled.
        tail_ratio: sampled exceedance of the law's 99.9th percentile / 0.001.
        reason: why it could not be fitted ("" when fitted).
    """

    shape: float | None
    scale_levels: float | None
    median_level: float
    pixels: int
    tail_ratio: float | None
    reason: str = ""

    @property
    def fitted(self) -> bool:
        return self.shape is not None


def background_bands(laws: list[BandLaw]) -> np.ndarray:
    """(n_bands,) bool: the bands whose tail is the law's (module docstring)."""
    lo, hi = BACKGROUND_TAIL_LIMITS
    tail = np.array([np.nan if law.tail_ratio is None else law.tail_ratio for law in laws])
    ok = (tail >= lo) & (tail <= hi)
    if not ok.any():
        return ok
    return ok & (tail <= BACKGROUND_TAIL_SLACK * tail[ok].min())


def band_edges_m(ranges_m: np.ndarray, n_bands: int) -> np.ndarray:
    """(n + 1,) band edges [m]: n bands of (nearly) equal numbers of range bins, the first
    edge below the first bin, the last above the last bin."""
    r = np.asarray(ranges_m, np.float64)
    n = max(1, min(int(n_bands), r.size))
    cut = np.linspace(0, r.size, n + 1).round().astype(np.int64)
    inner = 0.5 * (r[cut[1:-1] - 1] + r[cut[1:-1]])
    step = float(r[-1] - r[0]) / max(r.size - 1, 1) or 1.0
    return np.concatenate([[r[0] - step / 2], inner, [r[-1] + step / 2]])


def band_of_ranges(ranges_m: np.ndarray, edges_m: np.ndarray) -> np.ndarray:
    """(n_ranges,) band index of each range bin (bins outside the edges: nearest band)."""
    idx = np.searchsorted(np.asarray(edges_m, np.float64), np.asarray(ranges_m), side="right") - 1
    return np.clip(idx, 0, len(edges_m) - 2)


def band_histograms(
    images: list[np.ndarray], bands: list[np.ndarray], n_bands: int, n_levels: int, res: int = 1
) -> np.ndarray:
    """(n_bands, (n_levels - 1) res + 1) counts of each level step (1/res of an image level)
    per band over the images (`bands[i]`: the band of each range row of `images[i]`)."""
    n_bins = (n_levels - 1) * res + 1
    hist = np.zeros((n_bands, n_bins), np.int64)
    for image, band in zip(images, bands, strict=True):
        scaled = np.rint(np.asarray(image, np.float64) * res)
        lv = np.clip(scaled, 0, n_bins - 1).astype(np.int64)
        code = band[:, None] * n_bins + lv
        hist += np.bincount(code.ravel(), minlength=n_bands * n_bins).reshape(hist.shape)
    return hist


def exceedance(level: np.ndarray | float, shape: float, scale: float, res: int = 1) -> np.ndarray:
    """P(value > L) for L on the grid of 1/res levels, under Weibull(shape, scale)
    quantised to the nearest grid step."""
    x = (np.asarray(level, np.float64) + 0.5 / res) / scale
    return np.exp(-(x**shape))


def fit_band(
    hist: np.ndarray, q_lo: float, q_hi: float, saturation_level: int, res: int = 1
) -> BandLaw:
    """Weibull-plot fit of one band's histogram (steps of 1/res level) over its central
    quantiles; shape and scale in image levels."""
    # Level 0 is no signal (blanked or unlit cells, e.g. a fan looking above the surface),
    # not background: it is left out of the fit (a band of zeros and noise would otherwise
    # fit a degenerate law).
    hist = np.concatenate([[0], hist[1:]])
    total = int(hist.sum())
    if total == 0:
        return BandLaw(None, None, 0.0, 0, None, "empty (every pixel 0)")
    cdf = np.cumsum(hist) / total
    levels = np.arange(hist.size) / res
    median = float(np.searchsorted(cdf, 0.5)) / res
    inside = (cdf >= q_lo) & (cdf <= q_hi)
    below, above = np.flatnonzero(cdf < q_lo), np.flatnonzero(cdf > q_hi)
    if below.size:
        inside[below[-1]] = True
    if above.size:
        inside[above[0]] = True
    inside &= (hist > 0) & (cdf < 1.0)
    if median >= saturation_level:
        return BandLaw(None, None, median, total, None, f"saturated (median level {median:g})")
    if np.count_nonzero(inside) < 2:
        return BandLaw(None, None, median, total, None, f"constant (level {median:g})")
    x = np.log(levels[inside] + 0.5 / res)
    y = np.log(-np.log1p(-cdf[inside]))
    k, c = np.polyfit(x, y, 1)
    if not np.isfinite(k) or k < MIN_SHAPE:
        return BandLaw(None, None, median, total, None, "no Weibull fit")
    scale = float(np.exp(-c / k))
    q_tail = scale * (-np.log(1 - BACKGROUND_TAIL_Q)) ** (1 / k) - 0.5 / res
    if q_tail >= saturation_level:  # the tail is clipped away: it cannot be checked
        return BandLaw(float(k), scale, median, total, None)
    above_q_tail = hist[levels > q_tail].sum() / total
    return BandLaw(float(k), scale, median, total, float(above_q_tail / (1 - BACKGROUND_TAIL_Q)))


def threshold_level(shape: float, scale: float, pfa: float, n_levels: int, res: int = 1) -> float:
    """The smallest L on the grid of 1/res levels with P(value > L) <= pfa (the top level
    n_levels - 1 if none)."""
    levels = np.arange((n_levels - 1) * res + 1) / res
    ok = np.flatnonzero(exceedance(levels, shape, scale, res) <= pfa)
    return float(levels[ok[0]]) if ok.size else float(n_levels - 1)


def local_threshold_factor(
    shape: float,
    scale: float,
    n_levels: int,
    train_hs: int,
    guard_hs: int,
    method: CfarMethod,
    rank: int,
    pfa_local: float,
    seed: int = 0,
    res: int = 1,
) -> float:
    """tau with P(I > tau * noise) = pfa_local on background drawn from the fitted law
    (deterministic: a fixed seed; levels quantised and clipped like the images)."""
    rng = np.random.default_rng(seed)
    draw = scale * rng.weibull(shape, MC_SHAPE)
    image = np.clip(np.rint(draw * res) / res, 0, n_levels - 1)
    noise = cfar_noise(image, train_hs, guard_hs, method, rank or train_hs)
    ok = np.isfinite(noise)
    ratio = np.divide(image[ok], noise[ok], out=np.full(int(ok.sum()), np.inf), where=noise[ok] > 0)
    tau = float(np.quantile(ratio, 1.0 - pfa_local, method="higher"))
    return tau if np.isfinite(tau) else float(n_levels)
