"""Image formation of a wide-aperture imaging sonar by ray casting (paper Sec. V.B analogue).

Per ping, every beam casts `aperture_samples` rays spread across the aperture (the
unresolved angle) with stratified fan offsets drawn from the beam's across-fan pattern
(Gaussian, FWHM `beam_width_deg`, wider than the beam spacing), all in one
`cast_rays` call. Each first hit returns

    I_ray = rho_class * cos(incidence)^n * b(e) * 10^(-2 alpha r / 10) / K,

rho = class reflectivity, b(e) a Gaussian beam pattern across the aperture (edge gain at
+-aperture/2), alpha the residual absorption after TVG, K the rays per beam. A ray's
energy is spread over the range interval its aperture stratum covers (halfway to the
ranges of its neighbours across the aperture that hit the same object), then
accumulated per (range bin, beam) with `np.bincount`. So elevation ambiguity is real:
a vertical piling at horizontal distance d fills ranges d .. d / cos(aperture / 2).
The 8-bit level is 255 (g I / I_sat)^gamma (gain g) times Rayleigh speckle plus additive
noise (Weibull amplitude; Rayleigh by default), the noise scaled by a range profile and
both drawn from a correlated field when the config asks (`sonarmap.sim.image_noise`).
Labels and the true unresolved angle come from the strongest contribution per pixel.
"""

from __future__ import annotations

import numpy as np
from scipy.special import gamma, ndtri

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.schemas.sonar import SonarPing
from sonarmap.sim.config import SonarConfig
from sonarmap.sim.image_noise import (
    gaussian_field,
    quantile_index,
    quantile_table,
    range_profile,
    rayleigh_unit_mean,
    weibull,
)
from sonarmap.sim.world import World
from sonarmap.stages.kernels.geometry import matrix_from_rpy_product, polar_to_xyz

__all__ = ["NEW_CLASS_REFLECTIVITY", "SonarModel"]

NEW_CLASS_REFLECTIVITY = 1.0
"""Reflectivity of a table class the sonar config does not list (that of a piling)."""

_NOISE_TABLE_SIZE = 65536
_N_PATTERNS = 16
"""Number of precomputed jittered ray fans per sonar; each ping draws one."""
"""Rayleigh noise is drawn by inverse CDF from this many quantiles (uint16 indices)."""


class SonarModel:
    """Renders `SonarPing`s of one sonar (config + which sonar it is)."""

    def __init__(self, cfg: SonarConfig, sonar: str, table: ClassTable = DEFAULT_TABLE) -> None:
        self.cfg = cfg
        self.sonar = sonar
        self.ranges_m = cfg.ranges_m()
        self.angles_rad = cfg.angles_rad()
        self.n_ranges, self.n_beams, self.k = cfg.n_ranges, cfg.n_beams, cfg.aperture_samples
        self._fan_sigma_rad = np.deg2rad(cfg.beam_width_deg) / (2.0 * np.sqrt(2.0 * np.log(2.0)))
        self.aperture_rad = np.deg2rad(cfg.aperture_deg)
        self._perm = np.random.default_rng(12345).permutation(self.k)
        roll = np.deg2rad(cfg.mounting.rpy_deg[0])
        self.R_unrolled_sensor = matrix_from_rpy_product([roll, 0.0, 0.0])
        table.check(cfg.reflectivity, f"{sonar}.reflectivity", unknown_ok=False)
        # A class of the table without a reflectivity of its own (one defined in config)
        # reflects like a piling; class 0 ('none') reflects nothing.
        refl = np.zeros(max(table.ids.values()) + 1)
        for name, cid in table.ids.items():
            refl[cid] = cfg.reflectivity.get(name, 0.0 if cid == 0 else NEW_CLASS_REFLECTIVITY)
        self._refl = refl
        half = self.aperture_rad / 2
        self._bp_k = -np.log(cfg.aperture_edge_gain) / half**2
        self._noise_table = _noise_table(cfg.noise_mean_level, cfg.noise_shape)
        self._gain = 10.0 ** (cfg.gain_db / 10.0)
        self._profile = range_profile(self.n_ranges, cfg.noise_range_slope_db)[:, None]
        self._noise_q = quantile_table(weibull(cfg.noise_mean_level, cfg.noise_shape))
        self._speckle_q = quantile_table(rayleigh_unit_mean)
        pattern_rng = np.random.default_rng([12345, cfg.n_beams, cfg.aperture_samples])
        self._patterns = [self._jittered_fan(pattern_rng) for _ in range(_N_PATTERNS)]

    def ray_directions(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """One of the precomputed jittered fans, drawn with `rng` (see `_jittered_fan`)."""
        return self._patterns[int(rng.integers(_N_PATTERNS))]

    def _jittered_fan(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Jittered ray fan in the sensor frame: per beam, K aperture angles evenly spaced
        (aperture / K apart, random phase per beam, so any target wider than aperture / K
        is hit), each with a fan offset from a different stratum of the beam's across-fan
        pattern (Latin hypercube). Offsets follow a Gaussian of FWHM `beam_width_deg` (inverse CDF of the
        stratified uniforms), so each beam integrates the scene with its beam pattern.

        Returns:
            dirs (B*K, 3) unit vectors (sensor frame), aperture angle e (B*K,) [rad].
        """
        b, k = self.n_beams, self.k
        u1, u2 = rng.random((b, 1)), rng.random((b, k))
        e = -self.aperture_rad / 2 + (np.arange(k)[None] + u1) / k * self.aperture_rad
        a = (
            self.angles_rad[:, None].astype(np.float64)
            + ndtri(np.clip((self._perm[None] + u2) / k, 0.005, 0.995)) * self._fan_sigma_rad
        )
        # Unit directions: Eq. 1 with R = 1 (bearing a across the fan, elevation e).
        dirs = polar_to_xyz(1.0, a, e).reshape(-1, 3)
        return dirs, e.ravel()

    def _footprint(
        self, t: np.ndarray, obj: np.ndarray, max_gap_m: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Range interval [lo, hi] (n,) each ray's aperture stratum covers [m].

        Rays of a beam are ordered across the aperture; the interval reaches halfway to
        each neighbour's range where the neighbour hits the same object within max_gap_m.
        """
        tt = t.reshape(self.n_beams, self.k)
        oo = obj.reshape(self.n_beams, self.k)
        with np.errstate(invalid="ignore"):
            gap = np.abs(tt[:, 1:] - tt[:, :-1])
        same = (oo[:, 1:] == oo[:, :-1]) & (oo[:, 1:] >= 0) & (gap < max_gap_m)
        mid = np.where(same, 0.5 * (tt[:, 1:] + tt[:, :-1]), np.nan)
        lo, hi = tt.copy(), tt.copy()
        lo[:, 1:] = np.fmin(lo[:, 1:], mid)
        lo[:, :-1] = np.fmin(lo[:, :-1], mid)
        hi[:, 1:] = np.fmax(hi[:, 1:], mid)
        hi[:, :-1] = np.fmax(hi[:, :-1], mid)
        return lo.ravel(), hi.ravel()

    def render(
        self, world: World, T_world_sonar: np.ndarray, rng: np.random.Generator, t_ns: int
    ) -> SonarPing:
        """One ping from sonar pose `T_world_sonar` (4, 4); randomness only from `rng`."""
        cfg = self.cfg
        dirs_s, e = self.ray_directions(rng)
        dirs_w = dirs_s @ T_world_sonar[:3, :3].T
        hit = world.cast(np.broadcast_to(T_world_sonar[:3, 3], dirs_w.shape), dirs_w)
        t = hit["t_hit"]
        res = cfg.range_resolution_m
        ok = np.flatnonzero(t < cfg.range_max_m + cfg.max_splat_bins * res)
        cls = hit["class_id"][ok]
        contrib = self._ray_intensity(t[ok], cls, e[ok], hit["normal"][ok], dirs_w[ok])
        truth = self._unresolved_angle(dirs_s[ok])
        r_lo, r_hi = self._footprint(t, hit["object_id"], cfg.max_splat_bins * res)
        pix, w, ray = self._splat(r_lo[ok], r_hi[ok], ok // self.k, contrib)
        size = self.n_ranges * self.n_beams
        intensity = np.bincount(pix, weights=w, minlength=size)
        # Strongest contribution per visible pixel -> label and truth angle.
        top_pix, top_ray = _strongest(pix, w, ray, size)
        visible = self._level(intensity[top_pix]) >= cfg.label_min_level
        labels = np.zeros(size, dtype=np.uint8)
        truth_img = np.full(size, np.nan, dtype=np.float32)
        labels[top_pix[visible]] = cls[top_ray[visible]]
        truth_img[top_pix[visible]] = truth[top_ray[visible]]
        shape = (self.n_ranges, self.n_beams)
        return SonarPing(
            t_ns=int(t_ns),
            sonar=self.sonar,
            image=self._to_uint8(intensity, rng).reshape(shape),
            ranges_m=self.ranges_m,
            angles_rad=self.angles_rad,
            labels=labels.reshape(shape),
            truth_angle_rad=truth_img.reshape(shape),
        )

    def _ray_intensity(
        self, r: np.ndarray, cls: np.ndarray, e: np.ndarray, normal: np.ndarray, d: np.ndarray
    ) -> np.ndarray:
        """Per-ray return: reflectivity, cos(incidence)^n, aperture beam pattern, absorption."""
        cfg = self.cfg
        cos_inc = np.clip(np.abs(np.einsum("ij,ij->i", normal, d)), 1e-3, 1.0)
        return (
            self._refl[cls]
            * cos_inc**cfg.incidence_exponent
            * np.exp(-self._bp_k * e**2)
            * 10.0 ** (-2.0 * cfg.absorption_db_per_m * r / 10.0)
            / self.k
        )

    def _unresolved_angle(self, dirs_s: np.ndarray) -> np.ndarray:
        """Elevation (horizontal sonar) or bearing (vertical) of sensor-frame directions,
        in the unrolled frame at the sonar origin [rad]."""
        d_u = dirs_s @ self.R_unrolled_sensor.T
        if self.sonar == "horizontal":
            return np.arcsin(np.clip(d_u[:, 2], -1.0, 1.0))
        return np.arctan2(d_u[:, 1], d_u[:, 0])

    def _splat(
        self, r_lo: np.ndarray, r_hi: np.ndarray, beam: np.ndarray, contrib: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Share each ray's return evenly over the range bins of [r_lo, r_hi].

        Returns:
            pixel index bin * n_beams + beam, weight, ray index (all (m,)).
        """
        res = self.cfg.range_resolution_m
        lo = np.floor(r_lo / res).astype(np.int64)
        n = np.floor(r_hi / res).astype(np.int64) - lo + 1
        ray = np.repeat(np.arange(len(lo)), n)
        first = np.repeat(np.cumsum(n) - n, n)
        bins = lo[ray] + (np.arange(len(ray)) - first)
        w = (contrib / n)[ray]
        keep = (bins >= 0) & (bins < self.n_ranges)
        ray, bins, w = ray[keep], bins[keep], w[keep]
        return bins * self.n_beams + beam[ray], w, ray

    def _level(self, intensity: np.ndarray) -> np.ndarray:
        """Noise-free 8-bit level 255 (I / I_sat)^gamma (unclipped)."""
        cfg = self.cfg
        return 255.0 * (self._gain * intensity / cfg.saturation_intensity) ** cfg.display_gamma

    def _to_uint8(self, intensity: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Speckle (multiplicative Rayleigh, unit mean), additive noise (`_noise_table`), uint8."""
        cfg = self.cfg
        if cfg.textured:
            return self._to_uint8_textured(intensity, rng)
        nz = np.flatnonzero(intensity)
        level_nz = self._level(intensity[nz])
        if cfg.speckle:
            level_nz *= rng.rayleigh(np.sqrt(2.0 / np.pi), len(nz))
        if cfg.noise_mean_level > 0:
            idx = rng.integers(0, _NOISE_TABLE_SIZE, len(intensity), dtype=np.uint16)
            image = self._noise_table[idx]
        else:
            image = np.zeros(len(intensity), dtype=np.uint8)
        image[nz] = np.minimum(image[nz] + level_nz + 0.5, 255.0).astype(np.uint8)
        return image

    def _to_uint8_textured(self, intensity: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """As `_to_uint8`, the noise and the speckle drawn from two correlated fields
        (`sonarmap.sim.image_noise`: unit-mean Rayleigh speckle, Weibull noise) and the
        noise scaled by the range profile; float32 throughout."""
        cfg = self.cfg
        shape = (2, self.n_ranges, self.n_beams)
        field = gaussian_field(rng, shape, cfg.noise_corr_range, cfg.noise_corr_beam)
        nz = np.flatnonzero(intensity)
        level_nz = self._level(intensity[nz]).astype(np.float32)
        if cfg.speckle:
            level_nz *= self._speckle_q[quantile_index(field[1].ravel()[nz])]
        if cfg.noise_mean_level > 0:
            image = (self._noise_q[quantile_index(field[0])] * self._profile).ravel()
        else:
            image = np.zeros(len(intensity), dtype=np.float32)
        image[nz] += level_nz
        image += np.float32(0.5)
        return np.minimum(image, np.float32(255.0), out=image).astype(np.uint8)


def _noise_table(mean_level: float, shape: float) -> np.ndarray:
    """(_NOISE_TABLE_SIZE,) uint8 quantiles of the additive noise: Weibull of the given
    mean and shape (inverse CDF lambda (-ln(1 - p))^(1/shape), lambda = mean / Gamma(1 +
    1/shape)). Shape 2 is Rayleigh, computed as before so default images keep their bytes."""
    p = (np.arange(_NOISE_TABLE_SIZE) + 0.5) / _NOISE_TABLE_SIZE
    if shape == 2.0:
        sigma = mean_level * np.sqrt(2.0 / np.pi)
        level = sigma * np.sqrt(-2.0 * np.log1p(-p))
    else:
        scale = mean_level / gamma(1.0 + 1.0 / shape)
        level = scale * (-np.log1p(-p)) ** (1.0 / shape)
    return np.minimum(np.rint(level), 255).astype(np.uint8)


def _strongest(
    pix: np.ndarray, w: np.ndarray, ray: np.ndarray, size: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per distinct pixel, the ray with the largest weight (ties: the later entry).

    Entries come grouped by ray in ascending ray order, each ray's entries with one weight
    (as `SonarModel._splat` makes them). So the rays are written into a pixel table in
    ascending (weight, ray) order and the last write wins: the strongest, the later of
    equals. Sorting the rays, not `np.maximum.at` over every entry, halves the cost.

    Returns:
        pixels (p,) ascending and their strongest rays (p,).
    """
    m = len(pix)
    if m == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    starts = np.flatnonzero(np.r_[True, ray[1:] != ray[:-1]])
    length = np.diff(np.r_[starts, m])
    order = np.argsort(w[starts], kind="stable")
    first, n = starts[order], length[order]
    entry = np.repeat(first - (np.cumsum(n) - n), n) + np.arange(m)
    top = np.full(size, -1, dtype=np.int64)
    top[pix[entry]] = ray[entry]
    top_pix = np.flatnonzero(top >= 0)
    return top_pix, top[top_pix]
