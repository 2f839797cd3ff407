"""Segmentation of one horizontal image's features into objects (paper Sec. IV.C).

Features are clustered with DBSCAN in the fan plane (`sonarmap.stages.kernels.clustering`: the
number of objects is not known a priori) and clusters with fewer than n features are
dropped as noise.

Two cluster rules of the authors' simulation code (docs/authors-code.md
Sec. 4.1 step 5), off by default (`sonarmap.stages.classify.objects.extract_objects`):
- minimum object area: the original kept clusters of more than 150 Cartesian pixels of
  its 5 cm simulated image. Our features are polar cells, whose size grows with range,
  so a cluster is measured by the Cartesian area its cells cover, sum of R dR dtheta
  over its features (`cell_areas_m2`; = its number of covered 5 cm pixels x 0.0025 m2):
  150 px is 0.375 m2.
- fan edge: the original dropped a cluster when 10 or more 5 cm pixels of its bounding
  box, padded by 5 px, lay outside the fan mask (max range, +-fan half-width): an object
  cut by the fan edge cannot be told from the end of a longer one (paper Sec. V.A).
  Here the sonar-frame box of the cluster, padded by `fan_edge_margin_m`, is rastered on
  the 5 cm grid and the area of the pixels whose centres lie outside the fan (beyond the
  last range bin's far edge or the outer beams' outer edges) is compared with a limit
  (`fan_outside_area_m2`). Dropped clusters are not objects: they get no object index,
  like clusters below `min_features`.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "FAN_EDGE_PIXEL_M",
    "cell_areas_m2",
    "cluster_boxes",
    "fan_limits",
    "fan_outside_area_m2",
    "keep_clusters",
    "majority_class",
]


FAN_EDGE_PIXEL_M = 0.05
"""Raster cell of the fan-edge rule [m]: the original's simulated Cartesian pixel."""


def keep_clusters(labels: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Drop clusters and renumber the others 0..k'-1 in their order.

    Args:
        labels: (n,) object index 0..k-1 or -1.
        keep: (k,) bool, the clusters to keep.

    Returns:
        (n,) int64 labels, -1 for the dropped clusters' features.
    """
    remap = np.where(keep, np.cumsum(keep) - 1, -1).astype(np.int64)
    return np.where(labels >= 0, np.r_[remap, -1][labels], -1).astype(np.int64)


def cell_areas_m2(
    ranges_m: np.ndarray, angles_rad: np.ndarray, range_bin: np.ndarray, beam: np.ndarray
) -> np.ndarray:
    """Fan-plane area of polar image cells, R dR dtheta (paper Eq. 1 with phi = 0).

    dR and dtheta are the local spacings of the range and beam tables (np.gradient, so an
    uneven beam table is honoured); the cells tile the fan, so the area of a set of cells
    is the Cartesian area they cover.

    Args:
        ranges_m: (n_ranges,) ascending bin-centre ranges [m] (at least 2).
        angles_rad: (n_beams,) ascending beam bearings [rad] (at least 2).
        range_bin, beam: (n,) cell indices.

    Returns:
        (n,) float64 areas [m2].
    """
    r = np.asarray(ranges_m, np.float64)
    a = np.asarray(angles_rad, np.float64)
    dr, da = np.abs(np.gradient(r)), np.abs(np.gradient(a))
    return r[range_bin] * dr[range_bin] * da[beam]


def fan_outside_area_m2(
    boxes: np.ndarray,
    margin_m: float,
    range_max_m: float,
    angle_min_rad: float,
    angle_max_rad: float,
    pixel_m: float = FAN_EDGE_PIXEL_M,
) -> np.ndarray:
    """Area of each padded box outside the sonar fan, rastered on a fixed pixel grid.

    The grid is anchored at the sonar (cells [i p, (i + 1) p)); the cells whose centres lie
    in a box grown by `margin_m` on each side raster it, and count when their centre lies
    beyond `range_max_m` or outside [angle_min_rad, angle_max_rad].

    Args:
        boxes: (k, 4) (x_min, x_max, y_min, y_max) [m], sonar frame.
        margin_m: padding on each side [m] (original: 5 px).
        range_max_m: far edge of the fan [m].
        angle_min_rad, angle_max_rad: the fan's bearing limits [rad].
        pixel_m: grid cell [m].

    Returns:
        (k,) float64 area outside the fan [m2] (pixels x pixel_m^2).
    """
    k = len(boxes)
    if k == 0:
        return np.zeros(0, np.float64)
    lo = np.ceil((boxes[:, [0, 2]] - margin_m) / pixel_m - 0.5).astype(np.int64)
    hi = np.floor((boxes[:, [1, 3]] + margin_m) / pixel_m - 0.5).astype(np.int64)
    n = np.maximum(hi - lo + 1, 0)  # (k, 2) cells along x, y
    per_box = n[:, 0] * n[:, 1]
    box = np.repeat(np.arange(k), per_box)
    q = np.arange(len(box)) - np.repeat(np.cumsum(per_box) - per_box, per_box)
    x = (lo[box, 0] + q // n[box, 1] + 0.5) * pixel_m
    y = (lo[box, 1] + q % n[box, 1] + 0.5) * pixel_m
    a = np.arctan2(y, x)
    outside = (np.hypot(x, y) > range_max_m) | (a < angle_min_rad) | (a > angle_max_rad)
    return np.bincount(box, weights=outside.astype(np.float64), minlength=k) * pixel_m**2


def fan_limits(ranges_m: np.ndarray, angles_rad: np.ndarray) -> tuple[float, float, float]:
    """(far range, first beam's outer edge, last beam's outer edge) of a polar image."""
    r = np.asarray(ranges_m, np.float64)
    a = np.asarray(angles_rad, np.float64)
    return (
        float(r[-1] + (r[-1] - r[-2]) / 2),
        float(a[0] - (a[1] - a[0]) / 2),
        float(a[-1] + (a[-1] - a[-2]) / 2),
    )


def cluster_boxes(xy_m: np.ndarray, labels: np.ndarray, k: int) -> np.ndarray:
    """Axis-aligned bounding boxes of clusters.

    Args:
        xy_m: (n, 2) feature positions [m].
        labels: (n,) object index 0..k-1 or -1 (ignored).
        k: number of objects.

    Returns:
        (k, 4) float64 (x_min, x_max, y_min, y_max) [m].
    """
    boxes = np.empty((k, 4), dtype=np.float64)
    boxes[:, [0, 2]] = np.inf
    boxes[:, [1, 3]] = -np.inf
    m = labels >= 0
    lab, x, y = labels[m], xy_m[m, 0], xy_m[m, 1]
    np.minimum.at(boxes[:, 0], lab, x)
    np.maximum.at(boxes[:, 1], lab, x)
    np.minimum.at(boxes[:, 2], lab, y)
    np.maximum.at(boxes[:, 3], lab, y)
    return boxes


def majority_class(
    label_image: np.ndarray, range_bin: np.ndarray, beam: np.ndarray, labels: np.ndarray, k: int
) -> np.ndarray:
    """Majority ground-truth class of each object's cells (ties -> the smaller class id).

    Args:
        label_image: (n_ranges, n_beams) uint8 class ids (0 = none).
        range_bin, beam: (n,) cell indices of the features.
        labels: (n,) object index 0..k-1 or -1 (ignored).
        k: number of objects.

    Returns:
        (k,) int64 class ids.
    """
    n_cls = int(label_image.max(initial=0)) + 1
    m = labels >= 0
    cls = label_image[range_bin[m], beam[m]].astype(np.int64)
    votes = np.bincount(labels[m] * n_cls + cls, minlength=k * n_cls).reshape(k, n_cls)
    return votes.argmax(axis=1).astype(np.int64)
