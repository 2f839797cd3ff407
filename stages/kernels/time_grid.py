"""A sample of a recording's pings on a grid of absolute time, which extending or trimming
the recording at its end leaves in place (the front end's calibration sample, picked by
stage `keyframes` and calibrated on by stage `features`). Pure: no I/O."""

from __future__ import annotations

import numpy as np

__all__ = ["sampled_by_time"]


def sampled_by_time(t_ns: np.ndarray, n_sample: int) -> np.ndarray:
    """Positions of the pings nearest to `n_sample` ticks of a grid of absolute ping time
    (ties to the earlier ping), unique, ascending: the front end's calibration sample.

    Rule: the period P is the largest power of two nanoseconds with n_sample * P at most
    the recording's span D (so the ticks cover its first D/2 to D); the ticks are the first
    n_sample multiples of P from the first ping's time on. Extending the recording at its
    end, or trimming it there, keeps P (unless D crosses a power of two: a 10 % change
    does so with probability about 14 %) and the ticks, so the same pings are sampled
    (unless a trim cuts into the ticks), the thresholds are the same and so is every
    keyframe's detection unit. With at most n_sample pings (or a span under n_sample ns),
    all are sampled.
    """
    t = np.asarray(t_ns, np.int64)
    n = t.size
    span = int(t[-1] - t[0]) if n else 0
    if n <= n_sample or span < n_sample:
        return np.arange(n, dtype=np.int64)
    period = 1 << ((span // n_sample).bit_length() - 1)
    first = -(-int(t[0]) // period) * period
    ticks = first + period * np.arange(n_sample, dtype=np.int64)
    right = np.clip(np.searchsorted(t, ticks), 1, n - 1)
    left = right - 1
    pick = np.where(ticks - t[left] <= t[right] - ticks, left, right)
    return np.unique(pick)
