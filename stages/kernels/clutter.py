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
values in [v - 0.5, v + 0.5)), the points (ln(v + 0.5), ln(-ln(1 - F(v)))) whose F lies in
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

A band is called background (holds no return) when its sampled pixels exceed the fitted
law's 99th percentile between 1/2 and 2 times as often as the law says (1 %): its
upper tail is the law's, so detections there are false alarms (a band whose bulk is a
return, the seabed, has its tail clipped at the top level and fails the lower bound). The
detection rate measured there checks the law's extrapolation from the 99th percentile to p.

Pure numpy (no I/O); `sonarmap.stages.features.calibration` builds the recorded result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sonarmap.stages.kernels.cfar import CfarMethod, cfar_noise

__all__ = [
    "BandLaw",
    "band_edges_m",
    "band_histograms",
    "band_of_ranges",
    "exceedance",
    "fit_band",
    "local_threshold_factor",
    "threshold_level",
]

BACKGROUND_TAIL_Q = 0.99
"""A band is background when its pixels exceed the law's 99th percentile ..."""
BACKGROUND_TAIL_SLACK = 2.0
"""... between 1/2 and 2x as often as the law says (1 %)."""
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
        tail_ratio: sampled exceedance of the law's 99th percentile / 0.01.
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

    @property
    def background(self) -> bool:
        t = self.tail_ratio
        return t is not None and 1 / BACKGROUND_TAIL_SLACK <= t <= BACKGROUND_TAIL_SLACK


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
    images: list[np.ndarray], bands: list[np.ndarray], n_bands: int, n_levels: int
) -> np.ndarray:
    """(n_bands, n_levels) counts of each integer level per band over the images
    (`bands[i]`: the band of each range row of `images[i]`; levels clipped to the range)."""
    hist = np.zeros((n_bands, n_levels), np.int64)
    for image, band in zip(images, bands, strict=True):
        lv = np.clip(np.rint(np.asarray(image, np.float64)), 0, n_levels - 1).astype(np.int64)
        code = band[:, None] * n_levels + lv
        hist += np.bincount(code.ravel(), minlength=n_bands * n_levels).reshape(hist.shape)
    return hist


def exceedance(level: np.ndarray | float, shape: float, scale: float) -> np.ndarray:
    """P(integer level > L) under Weibull(shape, scale) quantised to the nearest level."""
    x = (np.asarray(level, np.float64) + 0.5) / scale
    return np.exp(-(x**shape))


def fit_band(hist: np.ndarray, q_lo: float, q_hi: float, saturation_level: int) -> BandLaw:
    """Weibull-plot fit of one band's level histogram over its central quantiles."""
    total = int(hist.sum())
    if total == 0:
        return BandLaw(None, None, 0.0, 0, None, "no pixels")
    cdf = np.cumsum(hist) / total
    levels = np.arange(hist.size)
    median = float(np.searchsorted(cdf, 0.5))
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
    x = np.log(levels[inside] + 0.5)
    y = np.log(-np.log1p(-cdf[inside]))
    k, c = np.polyfit(x, y, 1)
    if not np.isfinite(k) or k <= 0:
        return BandLaw(None, None, median, total, None, "no Weibull fit")
    scale = float(np.exp(-c / k))
    q99 = scale * (-np.log(1 - BACKGROUND_TAIL_Q)) ** (1 / k) - 0.5
    if q99 >= saturation_level:  # the tail is clipped away: it cannot be checked
        return BandLaw(float(k), scale, median, total, None)
    above_q99 = hist[levels > q99].sum() / total
    return BandLaw(float(k), scale, median, total, float(above_q99 / (1 - BACKGROUND_TAIL_Q)))


def threshold_level(shape: float, scale: float, pfa: float, n_levels: int) -> int:
    """The smallest integer level L with P(level > L) <= pfa (n_levels - 1 if none)."""
    levels = np.arange(n_levels)
    ok = np.flatnonzero(exceedance(levels, shape, scale) <= pfa)
    return int(ok[0]) if ok.size else n_levels - 1


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
) -> float:
    """tau with P(I > tau * noise) = pfa_local on background drawn from the fitted law
    (deterministic: a fixed seed; levels quantised and clipped like the images)."""
    rng = np.random.default_rng(seed)
    draw = scale * rng.weibull(shape, MC_SHAPE)
    image = np.clip(np.rint(draw), 0, n_levels - 1)
    noise = cfar_noise(image, train_hs, guard_hs, method, rank or train_hs)
    ok = np.isfinite(noise)
    ratio = np.divide(image[ok], noise[ok], out=np.full(int(ok.sum()), np.inf), where=noise[ok] > 0)
    tau = float(np.quantile(ratio, 1.0 - pfa_local, method="higher"))
    return tau if np.isfinite(tau) else float(n_levels)
