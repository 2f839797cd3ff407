"""Calibrate one sonar's detection thresholds from sampled pings (`sonarmap.stages.kernels.clutter`)
and turn a recorded calibration back into per-row thresholds.

The calibration is a JSON-ready dict (recorded in the features artifact's
`calibration.json`); `BandThresholds` is what detection reads of it, so the keyframes and
the submap frames between them are searched with the very same thresholds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from sonarmap.stages.kernels import clutter
from sonarmap.stages.kernels.cfar import CfarMethod, cfar_detect_rows, threshold_factor
from sonarmap.stages.kernels.lazy import lazy

__all__ = [
    "BandThresholds",
    "CalibrationSettings",
    "UnmodelableImages",
    "calibrate_sonar",
    "denoised",
    "thresholds",
]

ndimage = lazy("scipy.ndimage")

SOLVE_STEPS = 20
"""Bisection steps for the law's rate that meets p on the background bands."""
FILTER_SIZE = {
    "box3x3": (3, 3), "box3x5": (3, 5), "box5x3": (5, 3), "box5x5": (5, 5),
    "beam3": (1, 3), "range3": (3, 1),
}  # fmt: skip
"""(range, beam) cells of each mean filter."""
RESOLUTION = {"none": 1} | {m: r * b for m, (r, b) in FILTER_SIZE.items()}
"""Steps per image level of the filtered image (a mean of 9 integers moves by 1/9)."""
DIGITS = 6
"""Significant digits of the floats recorded (deterministic bytes)."""


class CalibrationSettings(Protocol):
    """What calibration reads of config section `features` (`FeaturesConfig`)."""

    @property
    def method(self) -> CfarMethod: ...
    @property
    def train_cells_per_side(self) -> int: ...
    @property
    def guard_cells_per_side(self) -> int: ...
    @property
    def pfa(self) -> float: ...
    @property
    def os_rank(self) -> int: ...
    @property
    def false_alarm_rate_per_cell(self) -> float: ...
    @property
    def intensity_floor(self) -> float | None: ...
    @property
    def threshold_factor(self) -> float | str | None: ...
    @property
    def range_bands(self) -> int: ...
    @property
    def fit_quantiles(self) -> tuple[float, float]: ...
    @property
    def denoise(self) -> str: ...


class UnmodelableImages(ValueError):
    """No range band of a sonar's sampled images can be fitted (saturated, empty, constant)
    while a threshold is to be measured."""


def denoised(image: np.ndarray, method: str) -> np.ndarray:
    """The image detection and calibration see: "boxRxB" = the mean of each cell's R x B
    neighbourhood (range x beam, edges repeated; "beam3" / "range3" along one axis),
    float; "none" = the image itself."""
    img = np.asarray(image)
    if method == "none":
        return img
    # float32 is exact for 25 x 255 and keeps the mean's 1/n-level steps (RESOLUTION)
    return ndimage.uniform_filter(img.astype(np.float32), FILTER_SIZE[method], mode="nearest")


def rounded(x: float | None) -> float | None:
    return None if x is None else float(f"{x:.{DIGITS}g}")


@dataclass(frozen=True)
class BandThresholds:
    """Per range band: edges [m], threshold factor tau and intensity floor [levels]; and
    the filter the calibration chose (`denoised`)."""

    edges_m: tuple[float, ...]
    tau: tuple[float, ...]
    floor_levels: tuple[float, ...]
    denoise: str = "none"

    def rows(self, ranges_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(tau, floor) of each range row."""
        band = clutter.band_of_ranges(ranges_m, np.asarray(self.edges_m))
        return np.asarray(self.tau)[band], np.asarray(self.floor_levels)[band]

    @classmethod
    def of(cls, sonar_doc: dict[str, Any]) -> BandThresholds:
        """From one sonar's entry of a calibration (`calibrate_sonar`)."""
        bands = sonar_doc["bands"]
        return cls(
            tuple(float(e) for e in sonar_doc["band_edges_m"]),
            tuple(float(b["threshold_factor"]) for b in bands),
            tuple(float(b["intensity_floor_levels"]) for b in bands),
            str(sonar_doc.get("denoise", "none")),
        )


def thresholds(doc: dict[str, Any]) -> dict[str, BandThresholds]:
    """What detection reads of a calibration (`calibration.json`), per sonar."""
    return {s: BandThresholds.of(e) for s, e in (doc.get("sonars") or {}).items()}


def _n_levels(images: Sequence[np.ndarray]) -> int:
    """Levels of the images' type: 256 for uint8, else up to the largest value seen."""
    if all(np.asarray(im).dtype == np.uint8 for im in images):
        return 256
    top = max(float(np.nanmax(im)) if np.size(im) else 0.0 for im in images)
    return int(min(max(top, 1.0), 65535.0)) + 1


def _borrow(laws: list[clutter.BandLaw]) -> list[int]:
    """For each band, the band whose law it uses: itself if fitted, else the nearest fitted."""
    fitted = np.flatnonzero([law.fitted for law in laws])
    idx = np.arange(len(laws))
    return fitted[np.abs(idx[:, None] - fitted[None, :]).argmin(axis=1)].tolist()


def calibrate_sonar(
    images: Sequence[np.ndarray],
    ranges_m: Sequence[np.ndarray],
    config: CalibrationSettings,
    sonar: str,
) -> dict[str, Any]:
    """One sonar's calibration (JSON-ready; module docstring of `clutter` for the rules).

    Raises:
        UnmodelableImages: no band can be fitted and a threshold is to be measured.
    """
    n_levels = _n_levels(images)
    method = config.denoise if config.denoise != "auto" else _auto_denoise(images, ranges_m, config)
    res = RESOLUTION[method]
    images = [denoised(im, method) for im in images]
    edges = clutter.band_edges_m(ranges_m[0], config.range_bands)
    n_bands = len(edges) - 1
    bands = [clutter.band_of_ranges(r, edges) for r in ranges_m]
    hist = clutter.band_histograms(list(images), bands, n_bands, n_levels, res)
    lo, hi = config.fit_quantiles
    laws = [clutter.fit_band(h, lo, hi, n_levels - 1, res) for h in hist]
    measured_floor = config.intensity_floor is None
    measured_tau = config.threshold_factor is None
    if not any(law.fitted for law in laws) and (measured_floor or measured_tau):
        reasons = sorted({law.reason for law in laws})
        raise UnmodelableImages(
            f"{sonar} sonar: no background to calibrate on in {len(images)} sampled"
            f" pings ({'; '.join(reasons)}); pin features.intensity_floor and"
            " features.threshold_factor to map it anyway"
        )
    source = _borrow(laws) if any(law.fitted for law in laws) else list(range(n_bands))
    p = config.false_alarm_rate_per_cell
    w = config.train_cells_per_side + config.guard_cells_per_side
    rows = np.bincount(bands[0], minlength=n_bands)
    interior = np.bincount(bands[0][w : max(len(bands[0]) - w, w)], minlength=n_bands)
    n_beams = int(np.asarray(images[0]).shape[1])
    rank = (config.os_rank or config.train_cells_per_side) if config.method == "os" else 0
    fits = [laws[source[b]] for b in range(n_bands)]
    taus = [_tau(fit, n_levels, config, rank, res) for fit in fits]
    floors = [_floor(fit, n_levels, config, p, res) for fit in fits]
    # The law's p-quantile must lie inside the levels for its rate to be checked.
    background = (clutter.background_bands(laws) & (np.asarray(floors) < n_levels - 1)).tolist()
    passing = None
    if measured_floor and any(background):
        # The law fixes how the floor moves with the rate; the sampled background bands fix
        # the level: the law's rate q that the floors are set for is solved (bisection in
        # log q, within p/20..20p) so that floor AND local test detect p per cell on the
        # sampled background bands (the local test rejects some exceedances, e.g. a bright
        # beam's, and the law's tail can be light). Recorded as the ratio p / q.
        kept = _background_values(images, ranges_m, edges, background, taus, config)
        q = _solve_rate(kept, fits, n_levels, config, p, res)
        passing = p / q
        floors = [_floor(fit, n_levels, config, q, res) for fit in fits]
    out_bands: list[dict[str, Any]] = []
    for b, law in enumerate(laws):
        fit = fits[b]
        rate = None
        if fit.fitted:
            rate = float(clutter.exceedance(floors[b], fit.shape, fit.scale_levels, res))
            rate *= passing if passing is not None else 1.0
        out_bands.append(
            {
                "rows": int(rows[b]),
                "median_level": rounded(law.median_level),
                "law": "weibull",
                "shape": rounded(law.shape),
                "scale_levels": rounded(law.scale_levels),
                "fit": "measured"
                if law.fitted
                else f"borrowed from band {source[b]} ({law.reason})",
                "background": bool(background[b]),
                "tail_ratio_q999": rounded(law.tail_ratio),
                "intensity_floor_levels": rounded(floors[b]),
                "threshold_factor": rounded(taus[b]),
                "expected_false_alarm_rate": rounded(rate),
                "expected_false_alarms_per_ping": None
                if rate is None
                else rounded(rate * float(interior[b]) * n_beams),
            }
        )
    known = [b["expected_false_alarms_per_ping"] for b in out_bands]
    return {
        "denoise": method,
        "band_edges_m": [rounded(float(e)) for e in edges],
        "bands": out_bands,
        "beams": n_beams,
        "levels": n_levels,
        "expected_false_alarms_per_ping": rounded(float(sum(k for k in known if k is not None))),
        "borrowed_bands": [b for b, law in enumerate(laws) if not law.fitted],
        "background_to_law_ratio": rounded(passing),
    }


def _auto_denoise(
    images: Sequence[np.ndarray], ranges_m: Sequence[np.ndarray], config: CalibrationSettings
) -> str:
    """`denoise: auto`: no filter unless detection without one is impossible: when more
    than half of the bands fitted on the unfiltered images put the stated rate's floor at
    the top level (a spiky background whose 1e-3 tail passes full scale; the filter moves
    returns by a cell, which costs the clean sensor map accuracy). Then a mean filter, the
    smallest of `SMOOTHING_WINDOWS` that averages as many independent looks as a 3x3 mean
    does on uncorrelated clutter of the fitted law (`_window_for_grain`)."""
    n_levels = _n_levels(images)
    edges = clutter.band_edges_m(ranges_m[0], config.range_bands)
    bands = [clutter.band_of_ranges(r, edges) for r in ranges_m]
    hist = clutter.band_histograms(list(images), bands, len(edges) - 1, n_levels)
    lo, hi = config.fit_quantiles
    fits = [f for f in (clutter.fit_band(h, lo, hi, n_levels - 1) for h in hist) if f.fitted]
    p = config.false_alarm_rate_per_cell
    top = sum(
        clutter.threshold_level(f.shape, f.scale_levels, p, n_levels) >= n_levels - 1  # type: ignore[arg-type]
        for f in fits
    )
    if fits and top <= len(fits) / 2:
        return "none"
    return _window_for_grain(images, fits) if fits else "box3x3"


SMOOTHING_WINDOWS = ("box3x3", "box3x5", "box5x3", "box5x5")
"""Candidate means for a spiky background, fewest cells first (range x beam)."""
LOOKS_SLACK = 1.1
"""A window qualifies when its spread is within 10 % of the iid 3x3 mean's (estimates of
both from a few pings vary by a few per cent)."""


def _spread(values: np.ndarray) -> float:
    """Interquartile range: the bulk's spread, which the objects (the upper tail) do not move."""
    q25, q75 = np.quantile(values, (0.25, 0.75))
    return float(q75 - q25)


def _window_for_grain(images: Sequence[np.ndarray], fits: list[clutter.BandLaw]) -> str:
    """The smallest mean window whose filtered images keep no more of the raw spread than a
    3x3 mean keeps of uncorrelated clutter of the same law.

    Why: a 3x3 mean averages 9 independent looks of uncorrelated speckle; real sensors'
    grain is correlated along range and beam (a real Oculus ping: lag-1 0.35 / 0.64), so the
    same 9 cells average fewer looks and the floor stays high. The target is the spread
    ratio (filtered / raw interquartile range) of a 3x3 mean over a fixed-seed iid image
    drawn from the median fitted law; each candidate's ratio is measured on the sampled
    images (pooled). Larger than 5x5 is not tried: a return would move by over two cells.
    """
    law = fits[len(fits) // 2]
    rng = np.random.default_rng(0)
    iid = (law.scale_levels or 1.0) * rng.weibull(law.shape or 1.0, clutter.MC_SHAPE)
    target = _spread(denoised(iid, "box3x3")) / _spread(iid)
    raw = np.concatenate([np.asarray(im, np.float32).ravel() for im in images])
    raw_spread = _spread(raw)
    if raw_spread <= 0:
        return "box3x3"
    for method in SMOOTHING_WINDOWS:
        filtered = np.concatenate([denoised(im, method).ravel() for im in images])
        if _spread(filtered) / raw_spread <= LOOKS_SLACK * target:
            return method
    return SMOOTHING_WINDOWS[-1]


def _floor(
    fit: clutter.BandLaw, n_levels: int, config: CalibrationSettings, p: float, res: int
) -> float:
    if config.intensity_floor is not None:
        return float(config.intensity_floor)
    return clutter.threshold_level(fit.shape, fit.scale_levels, p, n_levels, res)  # type: ignore[arg-type]


def _tau(
    fit: clutter.BandLaw, n_levels: int, config: CalibrationSettings, rank: int, res: int
) -> float:
    if config.threshold_factor == "exponential":
        return threshold_factor(config.method, 2 * config.train_cells_per_side, config.pfa, rank)
    if config.threshold_factor is not None:
        return float(config.threshold_factor)
    return clutter.local_threshold_factor(
        fit.shape, fit.scale_levels, n_levels, config.train_cells_per_side,  # type: ignore[arg-type]
        config.guard_cells_per_side, config.method, rank, config.pfa, res=res,
    )  # fmt: skip


def _background_values(
    images: Sequence[np.ndarray],
    ranges_m: Sequence[np.ndarray],
    edges: np.ndarray,
    background: list[bool],
    taus: list[float],
    config: CalibrationSettings,
) -> tuple[list[np.ndarray], int]:
    """Per band, the sorted (denoised) values of the sampled background pixels that pass
    the local test (empty for other bands); and the background cells counted."""
    bg = np.asarray(background)
    rank = (config.os_rank or config.train_cells_per_side) if config.method == "os" else 0
    w = config.train_cells_per_side + config.guard_cells_per_side
    found: list[list[np.ndarray]] = [[] for _ in background]
    cells = 0
    for image, r in zip(images, ranges_m, strict=True):
        band = clutter.band_of_ranges(r, edges)
        mask = cfar_detect_rows(
            image, config.train_cells_per_side, config.guard_cells_per_side,
            np.asarray(taus)[band], np.full(band.size, -np.inf), config.method, rank,
        )  # fmt: skip
        rows = bg[band]
        rows[:w] = False
        rows[max(rows.size - w, 0) :] = False
        cells += int(rows.sum()) * image.shape[1]
        for b in np.flatnonzero(bg):
            sel = rows & (band == b)
            found[b].append(np.asarray(image)[sel][mask[sel]])
    return [np.sort(np.concatenate(v)) if v else np.zeros(0) for v in found], cells


def _solve_rate(
    kept: tuple[list[np.ndarray], int],
    fits: list[clutter.BandLaw],
    n_levels: int,
    config: CalibrationSettings,
    p: float,
    res: int,
) -> float:
    """The law's rate q whose floors detect p per cell on the sampled background bands."""
    values, cells = kept
    if cells == 0:
        return p

    def rate(q: float) -> float:
        n = 0
        for b, v in enumerate(values):
            if v.size:
                floor = _floor(fits[b], n_levels, config, q, res)
                n += v.size - int(np.searchsorted(v, floor, side="right"))
        return n / cells

    lo, hi = np.log(p / 20), np.log(min(20 * p, 0.5))
    if rate(float(np.exp(lo))) >= p:
        return float(np.exp(lo))
    if rate(float(np.exp(hi))) <= p:
        return float(np.exp(hi))
    for _ in range(SOLVE_STEPS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if rate(float(np.exp(mid))) < p else (lo, mid)
    return float(np.exp(hi))
