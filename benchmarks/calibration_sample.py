"""How often the calibration's sample (and so its thresholds and every keyframe's detection
unit) survives a 10 % extension and a 10 % trim of a recording (issue 53).

For each keyframes.parquet given (a `keyframes/<key>/` artifact of a long recording), the
recording is cut at many lengths L (keyframes up to L of its span); for each, the sample
of the cut (`sampled_by_time`) is compared with the sample of the cut at 1.1 L
(extended) and at 0.9 L (trimmed). The same sample gives the same thresholds (the
calibration is deterministic), so the same units. Printed: the share of lengths whose
sample survives, for the time grid (features v5) and for the even spread over the
recording it replaced (v4).

    python benchmarks/calibration_sample.py data/store/keyframes/<key>/keyframes.parquet
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from sonarmap.stages.kernels.time_grid import sampled_by_time


def _even(t: np.ndarray, k: int) -> np.ndarray:
    """The v4 rule: k positions evenly spaced over all keyframes, first and last included."""
    n = t.size
    return np.unique(np.linspace(0, n - 1, min(k, n)).round().astype(np.int64))


Rule = Callable[[np.ndarray, int], np.ndarray]


def survival(t: np.ndarray, k: int, lengths: np.ndarray, rule: Rule) -> tuple[float, float]:
    """Shares of `lengths` [ns of span] whose sample equals the 1.1x and the 0.9x cut's."""
    t0 = t[0]

    def sample(span: float) -> list[int]:
        cut = t[t - t0 <= span]
        return t[rule(cut, k)].tolist()

    ext = np.mean([sample(L) == sample(1.1 * L) for L in lengths])
    trim = np.mean([sample(L) == sample(0.9 * L) for L in lengths])
    return float(ext), float(trim)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("keyframes", nargs="+", type=Path)
    ap.add_argument("-k", type=int, default=24, help="features.calibration_pings")
    ap.add_argument("--cuts", type=int, default=200, help="lengths tried per recording")
    args = ap.parse_args()
    for path in args.keyframes:
        t = np.sort(pq.read_table(path, columns=["t_ns"]).column("t_ns").to_numpy())
        span = float(t[-1] - t[0])
        # From a third of the recording to 1/1.1 of it, so the extension stays inside it.
        lengths = np.linspace(span / 3, span / 1.1, args.cuts)
        grid = survival(t, args.k, lengths, sampled_by_time)
        even = survival(t, args.k, lengths, _even)
        print(
            f"{path.parent.name[:12]}: {t.size} keyframes over {span / 1e9:.0f} s;"
            f" {args.cuts} lengths {lengths[0] / 1e9:.0f}-{lengths[-1] / 1e9:.0f} s:"
            f" sample kept by +10 % {100 * grid[0]:.0f} %, by -10 % {100 * grid[1]:.0f} %"
            f" (time grid); {100 * even[0]:.0f} % / {100 * even[1]:.0f} % (even spread, v4)"
        )


if __name__ == "__main__":
    main()
