"""Objects in one horizontal sonar image: DBSCAN clusters of features and their CNN patches.

Paper Sec. IV.C: image features are clustered with DBSCAN (the number of objects is
not known a priori), clusters with fewer than n features are dropped as noise, and a
bounding box around each object is resized to 40x40 pixels preserving its aspect ratio.

Geometry is metric, in the horizontal sonar's fan plane (REP 103, elevation unknown):
x = R cos(theta) forward, y = R sin(theta) left (paper Eq. 1 with phi = 0). Patches
are Cartesian views cut in each object's line-of-sight frame (rotated by the bearing of
its centroid), so the sonar is always straight below: row 0 is the far edge, column 0
the left edge, one pixel = side / size metres. This removes the bearing from an
object's appearance (a piling's arc always opens away from the bottom of the patch);
the paper does not say how its boxes were oriented.

The clusters themselves, and the authors' two optional cluster rules, are
`sonarmap.stages.classify.segmentation`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from sonarmap.schemas.sonar import SonarPing
from sonarmap.stages.classify.segmentation import (
    cell_areas_m2,
    cluster_boxes,
    fan_limits,
    fan_outside_area_m2,
    keep_clusters,
    majority_class,
)
from sonarmap.stages.kernels.clustering import cluster_features
from sonarmap.stages.kernels.geometry import fan_to_xy
from sonarmap.stages.kernels.lazy import lazy

ndimage = lazy("scipy.ndimage")

__all__ = [
    "PATCH_SIZE_PX",
    "KeyframeObjects",
    "crop_patches",
    "extract_objects",
    "horizontal_features",
    "los_rotate",
    "row_background",
]

PATCH_SIZE_PX = 40
"""Side of the CNN input patch [px] (paper: 40x40 grayscale)."""

GRAIN_QUANTILE = 0.9
"""Background level of normalisation "grain": this quantile over the beams of each range.
Grain correlated across beams (the real Oculus ping's lag-1 is 0.64) leaves blobs as
bright as a piling above the median; above the 90th percentile they go dark, while
objects, a minority of the beams at any range, stay above it (issue 50)."""


def _square_boxes(boxes: np.ndarray, margin_m: float, min_side_m: float) -> np.ndarray:
    """(k, 4) boxes grown by the margin -> (k, 3) square (x_centre, y_centre, side) [m]."""
    cx = (boxes[:, 0] + boxes[:, 1]) / 2
    cy = (boxes[:, 2] + boxes[:, 3]) / 2
    side = np.maximum(boxes[:, 1] - boxes[:, 0], boxes[:, 3] - boxes[:, 2]) + 2 * margin_m
    return np.stack([cx, cy, np.maximum(side, min_side_m)], axis=1)


def row_background(image: np.ndarray, quantile: float = 0.5) -> np.ndarray:
    """The image's background level at each range: (n_ranges,) `quantile` over the beams.

    Objects fill a minority of the beams at any range, so the median is the noise floor
    of that range (the additive noise and any range-dependent gain), whatever the sensor.
    """
    if quantile == 0.5:
        return np.median(image, axis=1).astype(np.float32)
    return np.quantile(image, quantile, axis=1).astype(np.float32)


def los_rotate(xy_m: np.ndarray, bearing_rad: np.ndarray) -> np.ndarray:
    """Rotate fan-plane points into line-of-sight frames.

    Args:
        xy_m: (n, 2) points [m] in the sonar frame.
        bearing_rad: (n,) bearing of each point's line-of-sight frame [rad].

    Returns:
        (n, 2) (u along the line of sight, away from the sonar; v across it, left) [m].
    """
    c, s = np.cos(bearing_rad), np.sin(bearing_rad)
    return np.stack([c * xy_m[:, 0] + s * xy_m[:, 1], -s * xy_m[:, 0] + c * xy_m[:, 1]], axis=1)


def crop_patches(
    image: np.ndarray,
    ranges_m: np.ndarray,
    angles_rad: np.ndarray,
    boxes: np.ndarray,
    bearing_rad: np.ndarray | None = None,
    *,
    margin_m: float,
    min_side_m: float = 0.0,
    size_px: int = PATCH_SIZE_PX,
    background: np.ndarray | None = None,
    peak_quantile: float = 0.99,
) -> np.ndarray:
    """Aspect-preserving Cartesian crops of a polar image, one per bounding box.

    Each box grown by `margin_m` is centred in a square of side max(width, height); the
    square is sampled on a size x size grid (bilinear in range bin and beam index, via
    the explicit angle table, so uneven beam spacing is honoured), and pixels outside
    the grown box are zero: the box is padded, never stretched. Each patch is divided
    by its maximum (gain invariance) to lie in [0, 1]; with `background` (the image's
    level per range bin, `row_background`), that level is first subtracted at each
    pixel's range and the patch is divided by the `peak_quantile` quantile of its box
    instead (one speckle spike does not set the scale), then clipped to [0, 1].

    With `bearing_rad`, box k is given in the line-of-sight frame of bearing_rad[k]
    (`los_rotate`) and the patch is cut in that frame: the sonar is always straight
    below the patch, whatever the object's bearing.

    Args:
        image: (n_ranges, n_beams) uint8 polar intensities.
        ranges_m: (n_ranges,) ascending bin-centre ranges [m].
        angles_rad: (n_beams,) ascending beam bearings [rad].
        boxes: (k, 4) (x_min, x_max, y_min, y_max) [m] (or (u, v) with bearing_rad).
        bearing_rad: optional (k,) line-of-sight bearing of each box's frame [rad].
        margin_m: margin added on each side of a box [m].
        min_side_m: smallest square side [m] (keeps tiny clusters from being blown up).
        size_px: patch side [px].
        background: optional (n_ranges,) background level per range bin [image levels].
        peak_quantile: with `background`, the quantile of the box's pixels scaled to 1.

    Returns:
        (k, size_px, size_px) float32 patches in [0, 1], row 0 = far, column 0 = left.
    """
    k = len(boxes)
    if k == 0:
        return np.zeros((0, size_px, size_px), dtype=np.float32)
    sq = _square_boxes(boxes, margin_m, min_side_m)
    g = (np.arange(size_px) + 0.5) / size_px - 0.5  # (size,) in [-0.5, 0.5)
    # Pixel centres [m]: rows go far -> near (u descending), columns left -> right.
    u = sq[:, 0, None, None] - g[None, :, None] * sq[:, 2, None, None]
    v = sq[:, 1, None, None] - g[None, None, :] * sq[:, 2, None, None]
    u, v = np.broadcast_arrays(u, v)
    inside = (
        (u >= boxes[:, 0, None, None] - margin_m)
        & (u <= boxes[:, 1, None, None] + margin_m)
        & (v >= boxes[:, 2, None, None] - margin_m)
        & (v <= boxes[:, 3, None, None] + margin_m)
    )
    b = np.zeros(k) if bearing_rad is None else np.asarray(bearing_rad, np.float64)
    c, s = np.cos(b)[:, None, None], np.sin(b)[:, None, None]
    x, y = c * u - s * v, s * u + c * v
    r = np.hypot(x, y)
    a = np.arctan2(y, x)
    n_r, n_b = len(ranges_m), len(angles_rad)
    row = np.interp(r, ranges_m, np.arange(n_r), left=-2.0, right=n_r + 1.0)
    col = np.interp(a, angles_rad, np.arange(n_b), left=-2.0, right=n_b + 1.0)
    vals = ndimage.map_coordinates(
        image.astype(np.float32), [row.ravel(), col.ravel()], order=1, mode="constant", cval=0.0
    ).reshape(k, size_px, size_px)
    vals *= inside
    if background is None:
        peak = vals.reshape(k, -1).max(axis=1)
        vals /= np.where(peak > 0, peak, 1.0)[:, None, None]
        return vals.astype(np.float32)
    # Above the background of each pixel's range (outside the image: none), so a bright
    # noise floor is not a bright patch; scaled by a high quantile of the box, not its
    # one brightest speckle.
    level = np.interp(row, np.arange(n_r), np.asarray(background, np.float32))
    vals = np.clip(vals - level.astype(np.float32), 0.0, None) * inside
    flat = np.where(inside, vals, np.nan).reshape(k, -1)
    peak = np.nan_to_num(np.nanquantile(flat, peak_quantile, axis=1))
    vals /= np.where(peak > 0, peak, 1.0)[:, None, None]
    return np.clip(vals, 0.0, 1.0).astype(np.float32)


@dataclass(frozen=True)
class KeyframeObjects:
    """The objects found in one keyframe's horizontal image.

    Attributes:
        feature_index: (n,) int64 row index (into the keyframe's feature arrays) of
            every feature that belongs to a kept object.
        object_index: (n,) int64 object index 0..k-1 of those features.
        boxes: (k, 4) float64 (x_min, x_max, y_min, y_max) [m], sonar frame.
        centroid_xy: (k, 2) float64 mean feature position [m].
        n_features: (k,) int64 cluster sizes.
        patches: (k, size, size) float32 CNN inputs in [0, 1], cut in each object's
            line-of-sight frame (centroid bearing): the sonar is below every patch.
        true_class_id: (k,) int64 majority label-image class, or None without labels.
    """

    feature_index: np.ndarray
    object_index: np.ndarray
    boxes: np.ndarray
    centroid_xy: np.ndarray
    n_features: np.ndarray
    patches: np.ndarray
    true_class_id: np.ndarray | None

    @property
    def count(self) -> int:
        """Number of objects k."""
        return len(self.boxes)


def extract_objects(
    ping: SonarPing,
    range_bin: np.ndarray,
    beam: np.ndarray,
    range_m: np.ndarray,
    angle_rad: np.ndarray,
    *,
    eps_m: float,
    min_samples: int,
    min_features: int,
    margin_m: float,
    min_side_m: float,
    size_px: int = PATCH_SIZE_PX,
    min_area_m2: float | None = None,
    drop_fan_edge: bool = False,
    fan_edge_margin_m: float = 0.25,
    fan_edge_max_outside_m2: float = 0.025,
    normalisation: str = "peak",
) -> KeyframeObjects:
    """Cluster one horizontal image's features into objects and crop their patches.

    Args:
        ping: the horizontal sonar image (its `labels`, when present, give true classes).
        range_bin, beam: (n,) int cell indices of the features.
        range_m, angle_rad: (n,) feature range [m] and bearing [rad].
        eps_m, min_samples, min_features: see `cluster_features`.
        margin_m, min_side_m, size_px: see `crop_patches`.
        min_area_m2: keep only clusters whose cells cover more than this area
            (`cell_areas_m2`; None: no area rule; original sim: 150 px = 0.375 m2).
        drop_fan_edge: drop clusters whose bounding box, padded by `fan_edge_margin_m`,
            has at least `fan_edge_max_outside_m2` outside the fan (`fan_outside_area_m2`;
            original sim: 5 px padding, 10 px = 0.025 m2).
        normalisation: "peak": each patch divided by its maximum (models trained before
            issue 50); "background": the image's `row_background` subtracted at each
            pixel's range and the rest divided by the box's 99th percentile, clipped to
            [0, 1] (`crop_patches`), so a bright or speckled noise floor stays dark;
            "grain": the same above each range's `GRAIN_QUANTILE` quantile instead.

    Returns:
        The keyframe's objects (dropped clusters are none of them).
    """
    xy = fan_to_xy(range_m, angle_rad)
    labels = cluster_features(xy, eps_m, min_samples, min_features)
    k = int(labels.max(initial=-1)) + 1
    if k and (min_area_m2 is not None or drop_fan_edge):
        keep = np.ones(k, dtype=bool)
        member = labels >= 0
        if min_area_m2 is not None:
            area = cell_areas_m2(ping.ranges_m, ping.angles_rad, range_bin[member], beam[member])
            keep &= np.bincount(labels[member], weights=area, minlength=k) > min_area_m2
        if drop_fan_edge:
            outside = fan_outside_area_m2(
                cluster_boxes(xy, labels, k), fan_edge_margin_m,
                *fan_limits(ping.ranges_m, ping.angles_rad),
            )  # fmt: skip
            keep &= outside < fan_edge_max_outside_m2
        labels = keep_clusters(labels, keep)
        k = int(keep.sum())
    boxes = cluster_boxes(xy, labels, k)
    member = np.flatnonzero(labels >= 0)
    counts = np.bincount(labels[member], minlength=k)
    sums = np.stack(
        [np.bincount(labels[member], weights=xy[member, i], minlength=k) for i in (0, 1)], axis=1
    )
    centroid = sums / np.maximum(counts, 1)[:, None]
    los_bearing = np.arctan2(centroid[:, 1], centroid[:, 0])
    uv = los_rotate(xy[member], los_bearing[labels[member]])
    los_boxes = cluster_boxes(uv, labels[member], k)
    patches = crop_patches(
        ping.image, ping.ranges_m, ping.angles_rad, los_boxes, los_bearing,
        margin_m=margin_m, min_side_m=min_side_m, size_px=size_px,
        background=_background(ping.image, normalisation),
    )  # fmt: skip
    truth = None
    if ping.labels is not None:
        truth = majority_class(ping.labels, range_bin, beam, labels, k)
    return KeyframeObjects(
        feature_index=member.astype(np.int64),
        object_index=labels[member],
        boxes=boxes,
        centroid_xy=centroid,
        n_features=counts.astype(np.int64),
        patches=patches,
        true_class_id=truth,
    )


def _background(image: np.ndarray, normalisation: str) -> np.ndarray | None:
    if normalisation == "peak":
        return None
    return row_background(image, GRAIN_QUANTILE if normalisation == "grain" else 0.5)


FEATURE_COLUMNS: tuple[str, ...] = ("feature_id", "range_bin", "beam", "range_m", "angle_rad")
"""Columns of features.parquet that object extraction reads (besides keyframe_id, sonar)."""


def horizontal_features(table: pa.Table) -> dict[int, dict[str, np.ndarray]]:
    """Split a features table into per-keyframe arrays of its horizontal-sonar rows.

    Args:
        table: features.parquet (keyframe_id, feature_id, sonar, range_bin, beam,
            range_m, angle_rad, ...).

    Returns:
        {keyframe_id: {column: (n,) array}} with rows sorted by feature_id.

    Raises:
        ValueError: a required column is missing.
    """
    missing = [c for c in ("keyframe_id", "sonar", *FEATURE_COLUMNS) if c not in table.column_names]
    if missing:
        raise ValueError(f"features table lacks columns {missing}")
    horiz = table.filter(pc.equal(table["sonar"], "horizontal"))
    kf = horiz["keyframe_id"].to_numpy().astype(np.int64)
    cols = {c: horiz[c].to_numpy() for c in FEATURE_COLUMNS}
    order = np.lexsort((cols["feature_id"], kf))
    kf = kf[order]
    if len(kf) == 0:
        return {}
    starts = np.flatnonzero(np.r_[True, kf[1:] != kf[:-1]])
    ends = np.r_[starts[1:], len(kf)].astype(int)
    return {
        int(kf[s]): {c: v[order[s:e]] for c, v in cols.items()}
        for s, e in zip(starts, ends, strict=True)
    }
