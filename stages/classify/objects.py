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

Two cluster rules of the authors' simulation code (reference/original-implementation.md
Sec. 4.1 step 5), off by default (`extract_objects`):
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

from dataclasses import dataclass

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from schemas.sonar import SonarPing
from stages._lazy import lazy

ndimage = lazy("scipy.ndimage")
spatial = lazy("scipy.spatial")
sparse = lazy("scipy.sparse")
csgraph = lazy("scipy.sparse.csgraph")
sk_cluster = lazy("sklearn.cluster")

__all__ = [
    "FAN_EDGE_PIXEL_M",
    "PATCH_SIZE_PX",
    "KeyframeObjects",
    "cell_areas_m2",
    "cluster_boxes",
    "cluster_features",
    "crop_patches",
    "extract_objects",
    "fan_outside_area_m2",
    "fan_xy",
    "horizontal_features",
    "keep_clusters",
    "los_rotate",
    "majority_class",
]

PATCH_SIZE_PX = 40
"""Side of the CNN input patch [px] (paper: 40x40 grayscale)."""

FAN_EDGE_PIXEL_M = 0.05
"""Raster cell of the fan-edge rule [m]: the original's simulated Cartesian pixel."""


def fan_xy(range_m: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Polar features -> fan-plane Cartesian (paper Eq. 1 with phi = 0).

    Args:
        range_m: (n,) ranges [m].
        angle_rad: (n,) bearings theta [rad], positive left.

    Returns:
        (n, 2) float64 (x forward, y left) [m] in the horizontal sonar frame.
    """
    r = np.asarray(range_m, dtype=np.float64)
    a = np.asarray(angle_rad, dtype=np.float64)
    return np.stack([r * np.cos(a), r * np.sin(a)], axis=1)


def cluster_features(
    xy_m: np.ndarray, eps_m: float, min_samples: int, min_features: int
) -> np.ndarray:
    """DBSCAN clusters of features, keeping clusters with at least `min_features` members.

    Args:
        xy_m: (n, 2) feature positions [m].
        eps_m: DBSCAN neighbourhood radius [m].
        min_samples: DBSCAN core-point neighbourhood count (the point itself included).
        min_features: smallest cluster kept (paper's n).

    Returns:
        (n,) int64 object index per feature, 0..k-1 numbered in order of each cluster's
        first feature, -1 for DBSCAN noise and dropped clusters.
    """
    n = len(xy_m)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    if min_samples <= 2:
        raw = _linked_components(xy_m, eps_m, min_samples)
    else:
        raw = sk_cluster.DBSCAN(eps=eps_m, min_samples=min_samples).fit_predict(xy_m)
    out = np.full(n, -1, dtype=np.int64)
    valid = raw >= 0
    if not valid.any():
        return out
    ids, first, counts = np.unique(raw[valid], return_index=True, return_counts=True)
    keep = counts >= min_features
    order = np.argsort(first[keep], kind="stable")
    remap = np.full(ids.max() + 1, -1, dtype=np.int64)
    remap[ids[keep][order]] = np.arange(int(keep.sum()))
    out[valid] = remap[raw[valid]]
    return out


def _linked_components(xy_m: np.ndarray, eps_m: float, min_samples: int) -> np.ndarray:
    """DBSCAN for min_samples <= 2, as connected components of the eps-neighbour graph.

    With min_samples 2 every point with a neighbour within eps is a core point, so each
    cluster is a connected component and the isolated points are noise (min_samples 1:
    they are singleton clusters). Same partition as scikit-learn's DBSCAN, at about a
    tenth of its per-keyframe overhead (its radius queries were 40 % of classify).
    """
    n = len(xy_m)
    pairs = spatial.cKDTree(xy_m).query_pairs(eps_m, output_type="ndarray")
    graph = sparse.coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), (n, n))
    _, comp = csgraph.connected_components(graph, directed=False)
    if min_samples == 2:
        isolated = np.bincount(comp, minlength=n)[comp] == 1
        comp = np.where(isolated, -1, comp)
    return comp.astype(np.int64)


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


def _fan_limits(ranges_m: np.ndarray, angles_rad: np.ndarray) -> tuple[float, float, float]:
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


def _square_boxes(boxes: np.ndarray, margin_m: float, min_side_m: float) -> np.ndarray:
    """(k, 4) boxes grown by the margin -> (k, 3) square (x_centre, y_centre, side) [m]."""
    cx = (boxes[:, 0] + boxes[:, 1]) / 2
    cy = (boxes[:, 2] + boxes[:, 3]) / 2
    side = np.maximum(boxes[:, 1] - boxes[:, 0], boxes[:, 3] - boxes[:, 2]) + 2 * margin_m
    return np.stack([cx, cy, np.maximum(side, min_side_m)], axis=1)


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
) -> np.ndarray:
    """Aspect-preserving Cartesian crops of a polar image, one per bounding box.

    Each box grown by `margin_m` is centred in a square of side max(width, height); the
    square is sampled on a size x size grid (bilinear in range bin and beam index, via
    the explicit angle table, so uneven beam spacing is honoured), and pixels outside
    the grown box are zero: the box is padded, never stretched. Each patch is divided
    by its maximum (gain invariance) to lie in [0, 1].

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
    peak = vals.reshape(k, -1).max(axis=1)
    vals /= np.where(peak > 0, peak, 1.0)[:, None, None]
    return vals.astype(np.float32)


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

    Returns:
        The keyframe's objects (dropped clusters are none of them).
    """
    xy = fan_xy(range_m, angle_rad)
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
                *_fan_limits(ping.ranges_m, ping.angles_rad),
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
