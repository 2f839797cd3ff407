"""Fusing one frame: orthogonal stereo association of its horizontal and vertical
features (paper Sec. IV.B), shared by stage `fuse` (keyframes) and stage `submaps`
(the frames between them).

Per frame:
1. Overlap: only horizontal features with |bearing| <= vertical aperture / 2 and vertical
   features with |fan angle| <= horizontal aperture / 2 take part.
2.-3. Subproblems per range bin, each solved optimally over the patch cost of Eq. 5, and
   the confidence of Eq. 6 per association: `sonarmap.stages.kernels.association`.
4. Point, Eq. 3: range R = (R_h + R_v) / 2, bearing theta from the horizontal feature,
   elevation from the vertical feature, as below; then Eq. 1 to Cartesian.

Geometry (deviation from Eq. 1 with phi = vertical angle): the vertical sonar's beam
angle a_v is its fan angle atan2(z, x) at its own origin, not asin(z / R), and the two
sonars are mounted apart, so Eq. 1 would misplace z (figures in
docs/decisions/007-fused-point-geometry.md). The point is computed exactly for any
rigid mounting: it lies on the horizontal sonar's
bearing half-plane (through its origin, normal (-sin theta, cos theta, 0)) and on the
vertical sonar's fan-angle plane (through its origin, normal R_hv (-sin a_v, cos a_v, 0)
in the horizontal frame, the vertical sensor's own fan angle being atan2(y_s, x_s)), at
distance R from the horizontal origin. The reported elevation is asin(z / R), so the row
satisfies Eq. 1 exactly. Square roots and arcsines are clamped: never NaN.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np

from sonarmap.schemas.sensors import Sensors
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.kernels.association import ConfidenceRule, assign_subproblems, image_patches

__all__ = ["FusionSettings", "fuse_keyframe", "fused_points", "sonar_offset"]


class FusionSettings(Protocol):
    """What fusion reads of config section `fuse` (`FuseConfig`)."""

    @property
    def patch_size_px(self) -> int: ...
    @property
    def horizontal_aperture_deg(self) -> float: ...
    @property
    def vertical_aperture_deg(self) -> float: ...
    @property
    def min_confidence(self) -> float: ...
    @property
    def rotate_vertical_patch(self) -> bool: ...
    @property
    def min_subproblem_features(self) -> int: ...
    @property
    def confidence_rule(self) -> ConfidenceRule: ...
    @property
    def max_cost_ratio(self) -> float | None: ...


def sonar_offset(sensors: Sensors | Mapping[str, Any]) -> np.ndarray:
    """(4, 4) T_h_v: the vertical sonar's pose in the horizontal sonar frame.

    Raises:
        ValueError: a sonar's T_base_sonar is missing or not a 4x4 rigid transform.
    """
    return Sensors.of(sensors).T_h_v


def fused_points(
    range_m: np.ndarray, bearing_rad: np.ndarray, fan_v_rad: np.ndarray, T_h_v: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """3D points from (range, horizontal bearing, vertical fan angle); see module docstring.

    Args:
        range_m: (n,) Eq. 3 range, from the horizontal sonar origin [m].
        bearing_rad: (n,) horizontal bearing theta [rad].
        fan_v_rad: (n,) vertical sonar fan angle (atan2(y, x) in its sensor frame) [rad].
        T_h_v: (4, 4) vertical sonar pose in the horizontal sonar frame.

    Returns:
        xyz (n, 3) in the horizontal sonar frame [m], elevation (n,) asin(z / R) [rad].
    """
    th, av = np.asarray(bearing_rad, np.float64), np.asarray(fan_v_rad, np.float64)
    r = np.asarray(range_m, np.float64)
    zeros = np.zeros_like(th)
    n_h = np.stack([-np.sin(th), np.cos(th), zeros], axis=1)
    n_v = np.stack([-np.sin(av), np.cos(av), zeros], axis=1) @ T_h_v[:3, :3].T
    h_v = n_v @ T_h_v[:3, 3]
    d = np.cross(n_h, n_v)
    dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-12)
    p0 = h_v[:, None] * np.cross(d, n_h) / dd[:, None]
    d_unit = d / np.sqrt(dd)[:, None]
    along = np.sqrt(np.maximum(r**2 - np.einsum("ij,ij->i", p0, p0), 0.0))
    forward = d_unit[:, 0] * np.cos(th) + d_unit[:, 1] * np.sin(th)
    xyz = p0 + np.where(forward >= 0, along, -along)[:, None] * d_unit
    elevation = np.arcsin(np.clip(xyz[:, 2] / np.maximum(r, 1e-12), -1.0, 1.0))
    return xyz, elevation


def _common_bins(range_m: np.ndarray, ranges_h_m: np.ndarray) -> np.ndarray:
    """Index of the horizontal range bin whose centre is nearest to each range [m].

    Subproblems pair features "at the same range" in the horizontal sonar's bins, so the
    vertical image may have its own range table (e.g. an M1200d beside an M750d); with
    equal tables this is the vertical feature's own range_bin.
    """
    mid = 0.5 * (ranges_h_m[1:] + ranges_h_m[:-1])
    return np.searchsorted(mid, range_m).astype(np.int64)


def fuse_keyframe(
    frame: KeyframeImages,
    feats: Mapping[str, np.ndarray],
    T_h_v: np.ndarray,
    config: FusionSettings,
) -> dict[str, np.ndarray]:
    """Fused points of one keyframe.

    Args:
        frame: the keyframe's two polar images.
        feats: this keyframe's features columns ("feature_id", "range_bin", "beam",
            "range_m", "angle_rad") and "is_horizontal" (bool, from `sonar`).
        T_h_v: vertical sonar pose in the horizontal sonar frame.

    Returns:
        {column: (k,) array} for the FUSED_SCHEMA columns except keyframe_id, sorted by
        feature_id_horizontal.
    """
    half_v = np.deg2rad(config.vertical_aperture_deg) / 2
    half_h = np.deg2rad(config.horizontal_aperture_deg) / 2
    is_h = feats["is_horizontal"]
    sel_h = np.flatnonzero(is_h & (np.abs(feats["angle_rad"]) <= half_v))
    sel_v = np.flatnonzero(~is_h & (np.abs(feats["angle_rad"]) <= half_h))
    bin_h_all = feats["range_bin"]
    bin_v_all = _common_bins(feats["range_m"], np.asarray(frame.horizontal.ranges_m, np.float64))
    sel_h = sel_h[np.argsort(bin_h_all[sel_h], kind="stable")]
    sel_v = sel_v[np.argsort(bin_v_all[sel_v], kind="stable")]
    size = config.patch_size_px
    p_h = image_patches(
        frame.horizontal.image, feats["range_bin"][sel_h], feats["beam"][sel_h], size
    )
    p_v = image_patches(frame.vertical.image, feats["range_bin"][sel_v], feats["beam"][sel_v], size)
    if config.rotate_vertical_patch:
        p_v = np.rot90(p_v, k=-1, axes=(1, 2))

    def cost_fn(i: np.ndarray, j: np.ndarray) -> np.ndarray:
        diff = p_h[i] - p_v[j]
        return np.sqrt(np.einsum("nab,nab->n", diff, diff, dtype=np.float64))

    i, j, cost, conf = assign_subproblems(
        bin_h_all[sel_h],
        bin_v_all[sel_v],
        cost_fn,
        min_features=config.min_subproblem_features,
        confidence_rule=config.confidence_rule,
    )
    keep = conf >= config.min_confidence
    if config.max_cost_ratio is not None:
        # rho < max  <=>  C = (1 - rho) / (1 + rho) > (1 - max) / (1 + max) (ratio rule).
        keep &= conf > (1.0 - config.max_cost_ratio) / (1.0 + config.max_cost_ratio)
    fh, fv = sel_h[i[keep]], sel_v[j[keep]]
    order = np.argsort(feats["feature_id"][fh], kind="stable")
    fh, fv = fh[order], fv[order]
    rng = 0.5 * (feats["range_m"][fh] + feats["range_m"][fv])
    bearing = feats["angle_rad"][fh]
    xyz, elevation = fused_points(rng, bearing, feats["angle_rad"][fv], T_h_v)
    return {
        "feature_id_horizontal": feats["feature_id"][fh],
        "feature_id_vertical": feats["feature_id"][fv],
        "range_m": rng,
        "bearing_rad": bearing.astype(np.float64),
        "elevation_rad": elevation,
        "x_m": xyz[:, 0],
        "y_m": xyz[:, 1],
        "z_m": xyz[:, 2],
        "cost": cost[keep][order],
        "confidence": conf[keep][order],
    }
