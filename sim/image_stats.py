"""Image character of an 8-bit sonar image: what a preset's `image:` block states.

The yardsticks shared by the real files (`benchmarks/sensor_stats.py`), the presets'
tests and the simulator's calibration, all on one polar image (rows: range bins, columns:
beams). The background is what lies at or below the image's 80th percentile (as
`sonarmap.sim.randomise.image_statistics`): brighter pixels are clipped to that level so
objects neither inflate nor break the correlations.
"""

from __future__ import annotations

import numpy as np

from sonarmap.sim.randomise import image_statistics

__all__ = ["BANDS", "background_lag1", "image_character", "range_bands"]

BANDS = 8
"""Range bands the range profile is given in (equal numbers of range bins)."""


def background_lag1(image: np.ndarray) -> tuple[float, float]:
    """(along range, along beams) lag-1 autocorrelation of the background.

    The image is clipped at its 80th percentile and each range row's mean is taken off
    first, so a range-dependent background (a trend, see `range_bands`) does not count as
    correlation: what is left is the speckle's and the noise's own grain.
    """
    x = np.asarray(image, np.float64)
    x = np.minimum(x, np.percentile(x, 80))
    x = x - x.mean(axis=1, keepdims=True)

    def lag1(a: np.ndarray, b: np.ndarray) -> float:
        den = np.sqrt((a * a).sum() * (b * b).sum())
        return float((a * b).sum() / den) if den > 0 else 0.0

    return lag1(x[:-1], x[1:]), lag1(x[:, :-1], x[:, 1:])


def range_bands(image: np.ndarray, bands: int = BANDS) -> tuple[list[float], float]:
    """Median level per range band (near to far) and the fitted range slope [dB].

    The slope is the least-squares line through 20 log10(band median) against the band
    centre as a share of the image's range span, over the whole span: the change of the
    background from the nearest to the farthest range bin (0 dB: flat).
    """
    x = np.asarray(image)
    medians = [float(np.median(b)) for b in np.array_split(x, bands, axis=0)]
    centres = (np.arange(bands) + 0.5) / bands
    db = 20.0 * np.log10(np.maximum(medians, 0.5))
    slope = float(np.polyfit(centres, db, 1)[0])
    return medians, slope


def image_character(images: list[np.ndarray]) -> dict[str, object]:
    """Median over `images` of each statistic (the `statistics:` of a preset's image block)."""
    rows = []
    for im in images:
        median, contrast = image_statistics(im)
        lag_r, lag_b = background_lag1(im)
        bands, slope = range_bands(im)
        rows.append((median, contrast, lag_r, lag_b, slope, bands))
    col = list(zip(*rows, strict=True))
    return {
        "images": len(images),
        "background_median": round(float(np.median(col[0])), 1),
        "speckle_contrast": round(float(np.median(col[1])), 3),
        "lag1_range": round(float(np.median(col[2])), 3),
        "lag1_beam": round(float(np.median(col[3])), 3),
        "range_slope_db": round(float(np.median(col[4])), 1),
        "band_medians": [round(float(v), 1) for v in np.median(np.array(col[5]), axis=0)],
    }
