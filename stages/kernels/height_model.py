"""Object-class height model P(z | range, bearing) (paper Sec. IV.D-E, Eq. 7-9).

One `HeightModel` per object class holds, for every cell of a sparse 2D grid over
the class's reference frame (`sonarmap.stages.kernels.object_frame`), a discrete posterior over the
height z of the return, stored as log probabilities on a fixed z grid.

- Cells: the reference frame is metric and aligned with the reference line of sight,
  so its first axis u is the range offset from the reference origin and its second
  axis v the arc length of the bearing offset (positive left, like the bearing).
  Cell (i, j) = (round(u / range_cell_m), round(v / cross_range_cell_m)) (cells
  centred on the origin, so range bins that sit on multiples of the cell size do not
  straddle cell borders); both
  indices may be negative, and only cells that received a measurement are stored
  (sorted int64 keys + rows of a growing array), so memory is bounded by the cells
  actually seen, not by a bounding box.
- Update (Eq. 7, Bayes' rule): the likelihood of a fused height z_k is a Gaussian
  N(z; z_k, sigma^2); all measurements of one call (one keyframe) that fall into the
  same cell are combined as a max-mixture L(z) = max_k N(z; z_k, sigma^2), so a cell
  seeing both the top and the bottom of an object keeps both modes. The prior is the
  cell's current posterior (uniform for a new cell). Log space throughout.
- Query (Eq. 8-9): MAP height separately over z <= 0 and z > 0. The confidence of
  each MAP value is its posterior probability P(|z - z_MAP| <= window), and only
  values above a threshold are returned (the original code declared but never used
  its threshold). A half's maximum that is not a local maximum of the whole
  posterior (it sits on the flank of a mode in the other half, e.g. at z = +step
  for a mode at z = 0) is not returned: it would duplicate that mode.

z is the Cartesian height in the horizontal sonar frame (z up), not the elevation
angle, as the paper says ("we estimate Cartesian z").
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from sonarmap.stages.kernels.choices import UpdateRule
from sonarmap.stages.kernels.lazy import lazy

special = lazy("scipy.special")

__all__ = ["HeightModel", "HeightQuery", "UpdateRule", "weighted", "z_grid"]

logger = logging.getLogger(__name__)


_OFFSET = 1 << 30
_STRIDE = 1 << 31


def z_grid(z_min_m: float, z_max_m: float, z_step_m: float) -> np.ndarray:
    """Fixed height grid (n_z,) [m], from z_min_m to z_max_m inclusive, spacing z_step_m.

    The bin values and the bin -> metre conversion are the same array (the original
    code used two inconsistent conversions).
    """
    if not z_max_m > z_min_m or z_step_m <= 0:
        raise ValueError(f"bad z grid: [{z_min_m}, {z_max_m}] step {z_step_m}")
    n = round((z_max_m - z_min_m) / z_step_m) + 1
    return np.linspace(z_min_m, z_max_m, n)


@dataclass(frozen=True)
class HeightQuery:
    """MAP heights of Eq. 8 (z <= 0) and Eq. 9 (z > 0) for n query positions.

    Attributes:
        z_low_m, z_high_m: (n,) MAP height in each half [m]; NaN where the cell was
            never updated or the value's confidence is below the threshold.
        conf_low, conf_high: (n,) posterior probability of each value (NaN like z).
        seen: (n,) bool, the position's cell has been updated (the rest predict nothing).
    """

    z_low_m: np.ndarray
    conf_low: np.ndarray
    z_high_m: np.ndarray
    conf_high: np.ndarray
    seen: np.ndarray


class HeightModel:
    """Sparse per-class grid of posteriors over height (paper Eq. 7-9).

    Args:
        z_m: (n_z,) ascending height grid [m] (see `z_grid`).
        sigma_m: standard deviation of the Gaussian height likelihood [m].
        range_cell_m: cell size along the reference range axis u [m].
        cross_range_cell_m: cell size along the reference cross-range axis v [m].
        window_m: half-width of the interval whose posterior mass is a MAP value's
            confidence [m].
    """

    def __init__(
        self,
        z_m: np.ndarray,
        sigma_m: float = 0.08,
        range_cell_m: float = 0.05,
        cross_range_cell_m: float = 0.1,
        window_m: float = 0.08,
        update_rule: UpdateRule = "product",
        prior_weight: float = 1.0,
    ) -> None:
        if sigma_m <= 0 or range_cell_m <= 0 or cross_range_cell_m <= 0 or window_m < 0:
            raise ValueError("sigma_m, cell sizes must be > 0 and window_m >= 0")
        if update_rule not in ("product", "mixture") or prior_weight <= 0:
            raise ValueError(f"bad update rule {update_rule!r} or prior weight {prior_weight}")
        self.update_rule = update_rule
        self.prior_weight = float(prior_weight)
        self.z_m = np.asarray(z_m, dtype=np.float64)
        self.sigma_m = float(sigma_m)
        self.cell_m = np.array([range_cell_m, cross_range_cell_m], dtype=np.float64)
        self.window_m = float(window_m)
        self._keys = np.empty(0, dtype=np.int64)
        self._sorted_keys = np.empty(0, dtype=np.int64)
        self._order = np.empty(0, dtype=np.int64)
        # Per cell: the normalised log posterior (product rule), or the Dirichlet counts
        # themselves (mixture rule: linear, so a query normalises by one division).
        self._mass = np.empty((16, self.z_m.size), dtype=np.float64)
        # Each cell's posterior probabilities, kept beside its mass: cells are queried
        # far more often than updated, so queries gather them instead of exponentiating.
        self._prob = np.empty_like(self._mass)
        self._split = int(np.searchsorted(self.z_m, 0.0, side="right"))  # z <= 0: [0, split)
        self.n_updates = 0

    @property
    def n_cells(self) -> int:
        """Number of cells that received at least one measurement."""
        return int(self._keys.size)

    @property
    def updated(self) -> bool:
        """True once Eq. 7 has been applied at least once."""
        return self.n_updates > 0

    def cells(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The learned cells in key order: (n, 2) int64 cell indices (i, j) (see
        `cell_keys`), and their (n, n_z) mass and posterior probabilities."""
        rows = self._order
        ij = np.stack(np.divmod(self._sorted_keys, _STRIDE), axis=1) - _OFFSET
        return ij, self._mass[rows], self._prob[rows]

    def restore(self, ij: np.ndarray, mass: np.ndarray, prob: np.ndarray, n_updates: int) -> None:
        """Replace the cells with those of `cells()` (of a model with this grid and
        rule), so the model answers and updates as the one they were taken from."""
        ij = np.asarray(ij, dtype=np.int64).reshape(-1, 2)
        shape = (ij.shape[0], self.z_m.size)
        if np.shape(mass) != shape or np.shape(prob) != shape:
            raise ValueError(f"cells: mass and probabilities must be {shape}")
        if ij.size and np.abs(ij).max() >= _OFFSET:
            raise ValueError("cells: index out of the cell index range")
        keys = (ij[:, 0] + _OFFSET) * _STRIDE + (ij[:, 1] + _OFFSET)
        if np.any(np.diff(keys) <= 0):
            raise ValueError("cells: indices must be unique and in key order")
        self._keys = keys
        self._order = np.arange(keys.size, dtype=np.int64)
        self._sorted_keys = keys
        self._mass = np.array(mass, dtype=np.float64, order="C")
        self._prob = np.array(prob, dtype=np.float64, order="C")
        self._reserve(16)
        self.n_updates = int(n_updates)

    def cell_keys(self, uv_m: np.ndarray) -> np.ndarray:
        """Packed int64 cell keys of (n, 2) reference-frame points (u, v) [m]."""
        ij = np.floor(np.asarray(uv_m, dtype=np.float64).reshape(-1, 2) / self.cell_m + 0.5)
        if ij.size and np.abs(ij).max() >= _OFFSET:
            raise ValueError("reference-frame coordinates out of the cell index range")
        ij = ij.astype(np.int64) + _OFFSET
        return ij[:, 0] * _STRIDE + ij[:, 1]

    def log_posterior(self, uv_m: np.ndarray) -> np.ndarray:
        """(n, n_z) log posteriors at (n, 2) points; rows of unseen cells are NaN."""
        rows = self._find(self.cell_keys(uv_m))
        out = np.full((rows.size, self.z_m.size), np.nan)
        seen = rows >= 0
        with np.errstate(divide="ignore"):
            out[seen] = np.log(self._probabilities(rows[seen]))
        return out

    def update(self, uv_m: np.ndarray, z_m: np.ndarray) -> int:
        """Apply Eq. 7 with one keyframe's fused heights of this class.

        Args:
            uv_m: (n, 2) reference-frame positions (u, v) of the fused points [m].
            z_m: (n,) measured heights in the horizontal sonar frame [m].

        Returns:
            Number of cells updated. Heights outside the z grid are ignored.
        """
        uv = np.asarray(uv_m, dtype=np.float64).reshape(-1, 2)
        z = np.asarray(z_m, dtype=np.float64).reshape(-1)
        inside = np.isfinite(z) & (z >= self.z_m[0]) & (z <= self.z_m[-1])
        if not inside.all():
            logger.debug("ignoring %d heights outside the z grid", int((~inside).sum()))
        uv, z = uv[inside], z[inside]
        if z.size == 0:
            return 0
        # Max-mixture of the measurements that share a cell (one keyframe).
        keys, inverse = np.unique(self.cell_keys(uv), return_inverse=True)
        order = np.argsort(inverse, kind="stable")
        log_lik = -0.5 * ((self.z_m[None, :] - z[order, None]) / self.sigma_m) ** 2
        starts = np.flatnonzero(np.r_[True, np.diff(inverse[order]) != 0])
        cell_log_lik = np.maximum.reduceat(log_lik, starts, axis=0)
        rows = self._find_or_insert(keys)
        if self.update_rule == "mixture":
            # Dirichlet-categorical: each keyframe's cell likelihood, normalised, is one
            # more (soft) count of the heights the cell returns from.
            lik = np.exp(cell_log_lik - cell_log_lik.max(axis=1, keepdims=True))
            self._mass[rows] += lik / lik.sum(axis=1, keepdims=True)
        else:
            # Bayes' rule: posterior = likelihood x prior, normalised (log space).
            post = self._mass[rows] + cell_log_lik
            self._mass[rows] = post - special.logsumexp(post, axis=1, keepdims=True)
        self._prob[rows] = self._mass_to_probabilities(self._mass[rows])
        self.n_updates += 1
        return int(keys.size)

    def query(
        self, uv_m: np.ndarray, threshold: float, prior: np.ndarray | None = None
    ) -> HeightQuery:
        """MAP heights over z <= 0 (Eq. 8) and z > 0 (Eq. 9) at (n, 2) positions.

        Args:
            uv_m: (n, 2) reference-frame positions [m].
            threshold: minimum confidence (posterior probability) of a returned value.
            prior: optional (n, n_z) non-negative weights that multiply each position's
                posterior before the MAP (renormalised; `sonarmap.stages.kernels.object_prior`).
        """
        rows = self._find(self.cell_keys(uv_m))
        seen = rows >= 0
        return self._answer(weighted(self._probabilities(rows[seen]), prior, seen), seen, threshold)

    def _answer(self, prob: np.ndarray, seen: np.ndarray, threshold: float) -> HeightQuery:
        """Eq. 8-9 from the (k, n_z) posteriors of the k positions of n that are `seen`."""
        cdf = None
        if self.update_rule == "product":
            cdf = np.concatenate([np.zeros((prob.shape[0], 1)), np.cumsum(prob, axis=1)], axis=1)
        out = []
        for half in (slice(0, self._split), slice(self._split, self.z_m.size)):
            z = np.full(seen.size, np.nan)
            conf = np.full(seen.size, np.nan)
            z[seen], conf[seen] = self._half_map(prob, cdf, half, threshold)
            out += [z, conf]
        return HeightQuery(*out, seen=seen)

    def _half_map(
        self, prob: np.ndarray, cdf: np.ndarray | None, half: slice, threshold: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """MAP height within one half of the z grid and its windowed posterior mass.

        Args:
            prob: (n, n_z) posteriors; cdf: (n, n_z + 1) their cumulative sums (product
                rule only: the mixture rule's confidence is the half's mass).
            half: the half's slice of the (ascending) z grid.
        """
        n, n_z = prob.shape
        in_half = prob[:, half]
        if n == 0 or in_half.shape[1] == 0:
            return np.full(n, np.nan), np.full(n, np.nan)
        best = half.start + np.argmax(in_half, axis=1)
        rows = np.arange(n)
        p_best = prob[rows, best]
        # A half's maximum on the flank of a mode of the other half is not a mode.
        below = np.where(best > 0, prob[rows, np.maximum(best - 1, 0)], -1.0)
        above = np.where(best < n_z - 1, prob[rows, np.minimum(best + 1, n_z - 1)], -1.0)
        is_mode = (p_best >= below) & (p_best >= above)
        z_map = self.z_m[best]
        if cdf is None:
            # Mixture rule: a cell returns from a spread of heights, so the evidence that
            # the structure is in this half at all is the half's share of the returns.
            conf = in_half.sum(axis=1)
        else:
            # Posterior mass of [z_MAP - window, z_MAP + window] (grid is uniform).
            lo = np.searchsorted(self.z_m, z_map - self.window_m - 1e-9, side="left")
            hi = np.searchsorted(self.z_m, z_map + self.window_m + 1e-9, side="right")
            conf = cdf[rows, hi] - cdf[rows, lo]
        keep = (conf > threshold) & is_mode
        return np.where(keep, z_map, np.nan), np.where(keep, conf, np.nan)

    def _probabilities(self, rows: np.ndarray) -> np.ndarray:
        """(n, n_z) posterior probabilities of cells (rows of the mass array)."""
        return self._prob[rows]

    def _mass_to_probabilities(self, mass: np.ndarray) -> np.ndarray:
        if self.update_rule == "mixture":
            return mass / mass.sum(axis=1, keepdims=True)
        return np.exp(mass)

    def _find(self, keys: np.ndarray) -> np.ndarray:
        """Row of each key in the posterior array, -1 for keys never seen."""
        if self._sorted_keys.size == 0:
            return np.full(keys.size, -1, dtype=np.int64)
        pos = np.searchsorted(self._sorted_keys, keys)
        pos_c = np.minimum(pos, self._sorted_keys.size - 1)
        hit = self._sorted_keys[pos_c] == keys
        return np.where(hit, self._order[pos_c], -1)

    def _find_or_insert(self, keys: np.ndarray) -> np.ndarray:
        """Rows of unique keys, adding uniform-prior rows for new ones."""
        rows = self._find(keys)
        new = rows < 0
        if new.any():
            n_old, n_new = self._keys.size, int(new.sum())
            self._reserve(n_old + n_new)
            if self.update_rule == "mixture":
                self._mass[n_old : n_old + n_new] = self.prior_weight / self.z_m.size
            else:
                self._mass[n_old : n_old + n_new] = np.log(1.0 / self.z_m.size)
            self._prob[n_old : n_old + n_new] = self._mass_to_probabilities(
                self._mass[n_old : n_old + n_new]
            )
            self._keys = np.concatenate([self._keys, keys[new]])
            self._order = np.argsort(self._keys, kind="stable")
            self._sorted_keys = self._keys[self._order]
            rows[new] = np.arange(n_old, n_old + n_new)
        return rows

    def _reserve(self, n_rows: int) -> None:
        """Grow the mass and probability arrays geometrically to hold n_rows cells."""
        if n_rows <= self._mass.shape[0]:
            return
        n_old, size = self._keys.size, max(n_rows, 2 * self._mass.shape[0])
        for name in ("_mass", "_prob"):
            grown = np.empty((size, self.z_m.size))
            grown[:n_old] = getattr(self, name)[:n_old]
            setattr(self, name, grown)


def weighted(prob: np.ndarray, prior: np.ndarray | None, seen: np.ndarray) -> np.ndarray:
    """The (k, n_z) posteriors of the k `seen` positions times their rows of the (n, n_z)
    `prior`, renormalised (unchanged without a prior or where the product is all zero)."""
    if prior is None:
        return prob
    product = prob * np.asarray(prior, dtype=np.float64)[seen]
    total = product.sum(axis=1, keepdims=True)
    return np.where(total > 0, product / np.where(total > 0, total, 1.0), prob)
