"""Correlated sonar noise: a Gaussian copula with separable AR(1) grain.

Real sonar images are not white: the pulse length and the beam pattern make neighbouring
range bins and beams alike (the real Oculus and ARIS images' background lag-1
autocorrelations are 0.2-0.6, `sonarmap.sim.image_stats`). A white Gaussian field is
filtered by a first-order recursion per axis (x_k = a x_{k-1} + sqrt(1 - a^2) z_k,
`scipy.signal.lfilter`, the first sample scaled to the stationary variance), which keeps
unit variance and gives lag-1 correlation `a` along that axis and a^|k| beyond. Mapped
through the normal CDF, each pixel is uniform (any marginal can be drawn by its inverse
CDF, here the Weibull of the additive noise and the Rayleigh of the speckle) while
neighbours stay alike. The exponential variate -ln(1 - u) is computed as -log_ndtr(-x),
exact in the tails where 1 - ndtr(x) would round to 0.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter
from scipy.special import gamma, log_ndtr

__all__ = ["exponential_field", "gaussian_field", "range_profile", "weibull_scale"]


def _ar1(x: np.ndarray, a: float, axis: int) -> np.ndarray:
    if a <= 0.0:
        return x
    first = [slice(None)] * x.ndim
    first[axis] = slice(0, 1)
    x[tuple(first)] /= np.float32(np.sqrt(1.0 - a * a))  # x_0 = z_0: stationary from the start
    return lfilter([np.sqrt(1.0 - a * a)], [1.0, -a], x, axis=axis).astype(np.float32, copy=False)


def gaussian_field(
    rng: np.random.Generator, shape: tuple[int, int], a_range: float, a_beam: float
) -> np.ndarray:
    """(n_ranges, n_beams) float32 standard normal field, lag-1 correlation `a_range` down
    the rows and `a_beam` across the columns (0: white along that axis)."""
    z = rng.standard_normal(shape, dtype=np.float32)
    return _ar1(_ar1(z, a_range, 0), a_beam, 1)


def exponential_field(x: np.ndarray) -> np.ndarray:
    """Unit exponential variates -ln(1 - Phi(x)) of a standard normal field (same shape)."""
    return -log_ndtr(-x)


def weibull_scale(mean: float, shape: float) -> float:
    """Weibull scale lambda of the given mean and shape: mean / Gamma(1 + 1/shape)."""
    return float(mean / gamma(1.0 + 1.0 / shape))


def range_profile(n_ranges: int, slope_db: float) -> np.ndarray:
    """(n_ranges,) float32 background factor: 0 dB at mid range, `slope_db` [dB of level,
    20 log10] from the nearest to the farthest bin, linear in dB (an exponential in range,
    as a TVG that over- or under-compensates the spreading and absorption)."""
    share = (np.arange(n_ranges) + 0.5) / n_ranges - 0.5
    return (10.0 ** (slope_db * share / 20.0)).astype(np.float32)
