"""Fuse: orthogonal stereo association of horizontal and vertical features (paper Sec. IV.B).

Per keyframe:
1. Overlap: only horizontal features with |bearing| <= vertical aperture / 2 and vertical
   features with |fan angle| <= horizontal aperture / 2 take part.
2. Subproblems: features in the same range bin of both images (paper: "features at the
   same range"; the vertical features' ranges are binned with the horizontal sonar's
   range table, so the two images may differ in resolution); each is solved optimally (minimum total cost) with
   `scipy.optimize.linear_sum_assignment` over the cost of Eq. 5,
       L(z_h, z_v) = || nu_h - rot90(nu_v) ||_F,
   nu = square patch (5x5 by default) around the feature in the image normalised per
   keyframe (level / image maximum), the vertical patch rotated 90 deg clockwise.
3. Confidence, Eq. 6, per association (i, j) of the solution: C = (L_2 - L_ij) / sum L,
   L_2 = the cheapest alternative of either feature (row i without j, column j without i),
   sum L = the sum of the costs of those candidates and L_ij. C < 0 when the solution had
   to give a feature a worse partner than its best; C = 1 when neither feature had an
   alternative. Associations with C < `min_confidence` are culled. The default (-1) culls
   none: on the simulator the patch cost does not predict 3D accuracy (low-cost pairs are
   mostly dim, weak detections), and culling at C >= 0 kept 593 of 3377 points of the
   test scene in tests/test_fuse.py and raised their median distance to the mesh from
   0.072 m to 0.113 m (within 0.3 m: 92.9 % -> 86.5 %). The paper-literal per-row form
   (best vs second-best candidate of the horizontal feature) did not predict it either.
   Options after the authors' code (reference/original-implementation.md Sec. 3.1 steps
   8-9), all off by default:
   - `min_subproblem_features`: a range bin is solved only when both its horizontal and
     its vertical set hold at least this many features (the original: more than 2);
     the features of smaller subproblems are never associated.
   - `confidence_rule="ratio"`: a deterministic analogue of the original's per-feature
     cost ratio. The original drew |L| random pairings of a subproblem (L the larger
     set, S the smaller) and took, per feature of S, the smallest over the second-smallest
     of the costs it was paired with; here every candidate is enumerated and an
     association (i, j) of the optimal solution gets rho = L_ij / L_2, L_2 = the cheapest
     other candidate of its feature in S: the horizontal one when the bin has fewer
     horizontal than vertical features, else (fewer vertical, or as many: the original
     does not say, the authors' later C++ matcher rates the vertical features) the
     vertical one. When the solution gives that feature its cheapest partner, rho is the
     original's smallest / second-smallest; otherwise rho >= 1 (the original still rated
     the feature by its best sampled cost, kept or not: here it is culled by any cut
     < 1). No alternative (a 1 x 1 subproblem): rho = 0, as Eq. 6 gives C = 1 there;
     0 / 0: rho = 1. The `confidence` column then holds C = (1 - rho) / (1 + rho) =
     (L_2 - L_ij) / (L_2 + L_ij), in [-1, 1] and decreasing in rho (rho = (1 - C) /
     (1 + C)); `min_confidence` still culls on it.
   - `max_cost_ratio`: with the ratio rule, keep only associations with rho below this
     (the original kept rows with ratio < 0.97 in simulation, 0.98 on real data), i.e.
     C > (1 - max) / (1 + max).
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
from typing import Any, Literal

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from pydantic import Field, model_validator

from schemas.fused import FUSED_SCHEMA
from schemas.sonar import KeyframeImages
from stages._lazy import lazy
from stages.base import Output, Stage, StageConfig

optimize = lazy("scipy.optimize")

__all__ = [
    "STAGE",
    "ConfidenceRule",
    "FuseConfig",
    "assign_subproblems",
    "fuse_keyframe",
    "fused_points",
    "image_patches",
    "sonar_offset",
]


ConfidenceRule = Literal["paper", "ratio"]
"""`fuse.confidence_rule`: "paper" = Eq. 6; "ratio" = the original code's cost ratio."""


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


def image_patches(image: np.ndarray, rows: np.ndarray, cols: np.ndarray, size: int) -> np.ndarray:
    """Square patches around cells of an image normalised to its maximum (zero-padded).

    Args:
        image: (n_ranges, n_beams) polar image.
        rows, cols: (n,) cell indices.
        size: odd patch side [pixels].

    Returns:
        (n, size, size) float32 patches in [0, 1], patch row = range, column = beam.
    """
    if size % 2 == 0:
        raise ValueError(f"patch size must be odd, got {size}")
    h = size // 2
    img = np.asarray(image)
    peak = float(img.max()) if img.size else 0.0
    d = np.arange(size)
    padded = np.pad(img, h)
    patches = padded[rows[:, None, None] + d[None, :, None], cols[:, None, None] + d[None, None, :]]
    return patches.astype(np.float32) / np.float32(peak if peak > 0 else 1.0)


def _same_bin_pairs(bin_h: np.ndarray, bin_v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All (i, j) with bin_h[i] == bin_v[j], grouped by bin, row-major within a bin.

    Both inputs must be sorted ascending. Returns (m,) int64 index arrays.
    """
    lo = np.searchsorted(bin_v, bin_h, side="left")
    n = np.searchsorted(bin_v, bin_h, side="right") - lo
    i = np.repeat(np.arange(len(bin_h)), n)
    first = np.repeat(np.cumsum(n) - n, n)
    j = lo[i] + (np.arange(len(i)) - first)
    return i.astype(np.int64), j.astype(np.int64)


def _confidence(
    i: np.ndarray,
    j: np.ndarray,
    cost: np.ndarray,
    chosen: np.ndarray,
    nh: int,
    nv: int,
    rule: ConfidenceRule = "paper",
) -> np.ndarray:
    """Confidence of the chosen candidate pairs (vectorised over all subproblems).

    Args:
        i, j, cost: (m,) all candidate pairs and their costs.
        chosen: (k,) indices into the candidates of the assigned pairs.
        nh, nv: numbers of horizontal / vertical features.
        rule: "paper" (Eq. 6) or "ratio" (module docstring).

    Returns:
        (k,) "paper": (L_2 - L_ij) / sum L, L_2 = cheapest alternative of either feature,
        sum over both features' candidates (the pair once); "ratio": (L_2 - L_ij) / (L_2 +
        L_ij) = (1 - rho) / (1 + rho), rho = L_ij / L_2, L_2 = cheapest alternative of
        the feature in the bin's smaller set (the vertical one if equal; C = 0, rho = 1,
        where both costs are 0). Both are 1 where there is no alternative.
    """
    others = np.ones(len(cost), dtype=bool)
    others[chosen] = False
    alt = np.where(others, cost, np.inf)
    row_min = np.full(nh, np.inf)
    col_min = np.full(nv, np.inf)
    np.minimum.at(row_min, i, alt)
    np.minimum.at(col_min, j, alt)
    ci, cj, cc = i[chosen], j[chosen], cost[chosen]
    if rule == "ratio":
        # Row i holds |V| candidates of its bin, column j |H|: rate the smaller set's feature.
        n_v, n_h = np.bincount(i, minlength=nh)[ci], np.bincount(j, minlength=nv)[cj]
        second = np.where(n_h < n_v, row_min[ci], col_min[cj])
        pair = np.where(np.isfinite(second), second + cc, 1.0)
        conf = np.where(pair > 0, (second - cc) / np.maximum(pair, 1e-300), 0.0)
        return np.where(np.isfinite(second), conf, 1.0)
    second = np.minimum(row_min[ci], col_min[cj])
    row_sum = np.bincount(i, weights=cost, minlength=nh)
    col_sum = np.bincount(j, weights=cost, minlength=nv)
    total = row_sum[ci] + col_sum[cj] - cc
    conf = np.where(total > 0, (second - cc) / np.maximum(total, 1e-12), 0.0)
    return np.where(np.isfinite(second), conf, 1.0)


def assign_subproblems(
    bin_h: np.ndarray,
    bin_v: np.ndarray,
    cost_fn: Any,
    *,
    min_features: int = 1,
    confidence_rule: ConfidenceRule = "paper",
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Minimum-cost assignment per range bin (Eq. 5) with Eq. 6 (or ratio) confidences.

    Args:
        bin_h, bin_v: (nh,), (nv,) sorted range bins of the horizontal / vertical features.
        cost_fn: cost_fn(i, j) -> (m,) costs of candidate pairs (index arrays).
        min_features: a bin is solved only if both of its sets hold at least this many
            features (the original code's gate: 3); the others are left unassigned.
        confidence_rule: "paper" (Eq. 6) or "ratio" (see `_confidence`).

    Returns:
        i, j (k,) int64 assigned feature indices (by bin, then i), cost (k,), confidence (k,).
    """
    i, j = _same_bin_pairs(bin_h, bin_v)
    if min_features > 1 and len(i):
        b = bin_h[i]
        n_h = np.searchsorted(bin_h, b, "right") - np.searchsorted(bin_h, b, "left")
        n_v = np.searchsorted(bin_v, b, "right") - np.searchsorted(bin_v, b, "left")
        used = (n_h >= min_features) & (n_v >= min_features)
        i, j = i[used], j[used]
    if len(i) == 0:
        e = np.zeros(0, np.int64)
        return e, e, np.zeros(0), np.zeros(0)
    cost = np.asarray(cost_fn(i, j), dtype=np.float64)
    bins = bin_h[i]
    starts = np.flatnonzero(np.r_[True, bins[1:] != bins[:-1]])
    ends = np.r_[starts[1:], len(i)]
    n_v = np.searchsorted(bin_v, bins[starts], "right") - np.searchsorted(bin_v, bins[starts])
    chosen = []
    for s, e, nv in zip(starts.tolist(), ends.tolist(), n_v.tolist(), strict=True):
        r, c = optimize.linear_sum_assignment(cost[s:e].reshape(-1, nv))
        chosen.append(s + r * nv + c)
    sel = np.concatenate(chosen)
    conf = _confidence(i, j, cost, sel, len(bin_h), len(bin_v), confidence_rule)
    return i[sel], j[sel], cost[sel], conf


def sonar_offset(sensors: Mapping[str, Any]) -> np.ndarray:
    """(4, 4) T_h_v: the vertical sonar's pose in the horizontal sonar frame.

    Raises:
        ValueError: a sonar's T_base_sonar is missing or not a 4x4 rigid transform.
    """
    mats = {}
    for s in ("horizontal", "vertical"):
        try:
            m = np.asarray(sensors[s]["T_base_sonar"], dtype=np.float64)
        except (KeyError, TypeError) as err:
            raise ValueError(f"fuse: sensors has no {s}.T_base_sonar") from err
        if m.shape != (4, 4) or not np.allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-6):
            raise ValueError(f"fuse: sensors.{s}.T_base_sonar is not a 4x4 rigid transform")
        mats[s] = m
    return np.linalg.inv(mats["horizontal"]) @ mats["vertical"]


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
    sensors: Mapping[str, Any],
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
    inputs=("keyframes.frames", "keyframes.sensors", "features.features"),
    outputs=(Output("fused", "parquet", "fused.parquet", schema=FUSED_SCHEMA),),
    run=run,
    description="orthogonal stereo association of horizontal and vertical features (Eq. 3, 5, 6)",
)
