"""Fuse: orthogonal stereo association of horizontal and vertical features (paper Sec. IV.B).

Per keyframe:
1. Overlap: only horizontal features with |bearing| <= vertical aperture / 2 and vertical
   features with |fan angle| <= horizontal aperture / 2 take part.
2.-3. Subproblems per range bin, each solved optimally over the patch cost of Eq. 5, and
   the confidence of Eq. 6 per association: `stages.fuse.association`.
4. Point, Eq. 3: range R = (R_h + R_v) / 2, bearing theta from the horizontal feature,
   elevation from the vertical feature, as below; then Eq. 1 to Cartesian.

Geometry (deviation from Eq. 1 with phi = vertical angle, measured): the vertical sonar's
beam angle a_v is its fan angle atan2(z, x) at its own origin, not asin(z / R). With the
vertical origin at the horizontal one, the point is x = R / sqrt(1 + tan^2 theta +
tan^2 a_v), y = x tan theta, z = x tan a_v, while Eq. 1 with phi = a_v puts z higher by
up to 0.25 % of R at the overlap corners (theta = a_v = 10 deg: 2.5 cm at 10 m). And the
vertical sonar sits `T_base_sonar`-offset from the horizontal one (default 0.1 m above):
ignoring that shifts z by about the offset (10 cm, a 1.9 deg elevation error at 3 m). So
the point is computed exactly for any rigid mounting: it lies on the horizontal sonar's
bearing half-plane (through its origin, normal (-sin theta, cos theta, 0)) and on the
vertical sonar's fan-angle plane (through its origin, normal R_hv (-sin a_v, cos a_v, 0)
in the horizontal frame, the vertical sensor's own fan angle being atan2(y_s, x_s)), at
distance R from the horizontal origin. The reported elevation is asin(z / R), so the row
satisfies Eq. 1 exactly. Square roots and arcsines are clamped: never NaN.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from pydantic import Field, model_validator

from schemas.fused import FUSED_SCHEMA
from schemas.sensors import Sensors
from schemas.sonar import KeyframeImages
from stages.base import Input, Output, Stage, StageConfig
from stages.fuse.association import ConfidenceRule, assign_subproblems, image_patches

__all__ = [
    "STAGE",
    "FuseConfig",
    "fuse_keyframe",
    "fused_points",
    "sonar_offset",
]


class FuseConfig(StageConfig):
    """Config section `fuse`.

    Attributes:
        patch_size_px: side of the square patch of Eq. 5 (odd) [pixels].
        horizontal_aperture_deg: vertical extent of the horizontal sonar's beams [deg].
        vertical_aperture_deg: horizontal extent of the vertical sonar's beams [deg].
        min_confidence: associations with confidence below this are culled (-1: none).
        rotate_vertical_patch: rotate the vertical patch 90 deg before comparing (paper).
        min_subproblem_features: smallest horizontal and vertical set of a solved range bin.
        confidence_rule: "paper" (Eq. 6) or "ratio" (the original code's; module docstring).
        max_cost_ratio: ratio rule only: keep associations with L_ij / L_2 below this.
    """

    patch_size_px: int = Field(5, ge=1, le=63)
    horizontal_aperture_deg: float = Field(20.0, gt=0.0, lt=180.0)
    vertical_aperture_deg: float = Field(20.0, gt=0.0, lt=180.0)
    min_confidence: float = Field(-1.0, ge=-1.0, le=1.0)
    rotate_vertical_patch: bool = True
    min_subproblem_features: int = Field(
        1,
        ge=1,
        le=100000,
        description="a range-bin subproblem is solved only if both its horizontal and its"
        " vertical set have at least this many features (1: every bin; original code: 3)",
    )
    confidence_rule: ConfidenceRule = Field(
        "paper",
        description="'paper': Eq. 6, (L_2 - L_ij) / sum L; 'ratio': rho = L_ij / L_2 of the"
        " bin's smaller-set feature, the original code's per-feature cost ratio, stored as"
        " confidence (1 - rho) / (1 + rho)",
    )
    max_cost_ratio: float | None = Field(
        None,
        gt=0.0,
        le=1.0,
        description="with confidence_rule 'ratio', keep associations whose cost ratio"
        " L_ij / L_2 is below this (None: keep all; original code 0.97 sim, 0.98 real)",
    )

    @model_validator(mode="after")
    def _ratio_cut_needs_ratio_rule(self) -> FuseConfig:
        if self.max_cost_ratio is not None and self.confidence_rule != "ratio":
            raise ValueError("max_cost_ratio needs confidence_rule 'ratio'")
        return self


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
    frame: KeyframeImages, feats: Mapping[str, np.ndarray], T_h_v: np.ndarray, config: FuseConfig
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


_FEATURE_COLUMNS = (
    "keyframe_id",
    "feature_id",
    "sonar",
    "range_bin",
    "beam",
    "range_m",
    "angle_rad",
)


def _feature_arrays(features: pa.Table) -> dict[str, np.ndarray]:
    """Feature columns as numpy, sorted by (keyframe_id, feature_id), `sonar` as a bool
    `is_horizontal`."""
    missing = [c for c in _FEATURE_COLUMNS if c not in features.column_names]
    if missing:
        raise ValueError(f"fuse: features table lacks columns {missing}")
    cols = {c: features.column(c).to_numpy() for c in _FEATURE_COLUMNS if c != "sonar"}
    is_h = pc.equal(features.column("sonar"), "horizontal")
    cols["is_horizontal"] = is_h.to_numpy(zero_copy_only=False).astype(bool)
    kf, fid = cols["keyframe_id"], cols["feature_id"]
    ordered = len(kf) < 2 or bool(
        np.all((kf[1:] > kf[:-1]) | ((kf[1:] == kf[:-1]) & (fid[1:] > fid[:-1])))
    )
    if ordered:
        return cols
    order = np.lexsort((fid, kf))
    return {c: v[order] for c, v in cols.items()}


def fuse_table(
    frames: Sequence[KeyframeImages],
    features: pa.Table,
    sensors: Sensors | Mapping[str, Any],
    config: FuseConfig,
) -> pa.Table:
    """`fused.parquet` for all keyframes (one keyframe's images in memory at a time)."""
    T_h_v = sonar_offset(sensors)
    cols = _feature_arrays(features)
    kf = cols["keyframe_id"]
    chunks: list[dict[str, np.ndarray]] = []
    for frame in frames:
        lo, hi = np.searchsorted(kf, [frame.keyframe_id, frame.keyframe_id + 1])
        if hi == lo:
            continue
        part = fuse_keyframe(frame, {c: v[lo:hi] for c, v in cols.items()}, T_h_v, config)
        part["keyframe_id"] = np.full(len(part["range_m"]), frame.keyframe_id, np.int64)
        chunks.append(part)
    if not chunks:
        return FUSED_SCHEMA.empty_table()
    arrays = [pa.array(np.concatenate([c[f.name] for c in chunks])) for f in FUSED_SCHEMA]
    return pa.Table.from_arrays(arrays, schema=FUSED_SCHEMA)


def run(config: FuseConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    """Stage entry point: keyframes.frames, keyframes.sensors, features.features -> fused."""
    table = fuse_table(
        inputs["keyframes.frames"], inputs["features.features"], inputs["keyframes.sensors"], config
    )
    return {"fused": table}


STAGE = Stage(
    name="fuse",
    version=1,
    config=FuseConfig,
    inputs=(
        Input("keyframes", "frames"),
        Input("keyframes", "sensors"),
        Input("features", "features"),
    ),
    outputs=(Output("fused", "parquet", "fused.parquet", schema=FUSED_SCHEMA),),
    run=run,
    description="orthogonal stereo association of horizontal and vertical features (Eq. 3, 5, 6)",
)
