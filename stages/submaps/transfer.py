"""Objects and classes of a submap frame, taken from the keyframe objects it sees again.

A submap frame is 0.1-2 m from its keyframe, so it sees the keyframe's objects again,
from nearly the same place. Its horizontal returns are clustered as the classifier
clusters a keyframe's (DBSCAN in the fan plane, `sonarmap.stages.kernels.clustering`), and
each cluster takes the object, and so the class, of the keyframe object that most of
its returns lie on: a return lies on an object when, moved into the keyframe's sonar
frame by the dead-reckoning motion between the two, it is within `match_radius_m` of
one of that object's returns. Objects of the next keyframe count too (a frame late in
its interval is closest to the next keyframe). A cluster that meets no object stays
unclassified.

This replaces the CNN on submap frames, because a keyframe's class is already pooled
over views and a transfer costs a fraction of a CNN pass
(docs/decisions/009-submap-classes-by-transfer.md).
"""

from __future__ import annotations

import numpy as np

from sonarmap.stages.kernels.clustering import cluster_features
from sonarmap.stages.kernels.geometry import fan_to_xy
from sonarmap.stages.kernels.lazy import lazy

spatial = lazy("scipy.spatial")

__all__ = ["KeyframeObjectPoints", "transfer_objects"]


class KeyframeObjectPoints:
    """The returns of one keyframe's objects in its horizontal sonar plane, indexed."""

    def __init__(self, xy_m: np.ndarray, object_id: np.ndarray) -> None:
        self.object_id = np.asarray(object_id, np.int64)
        self.tree = (
            spatial.cKDTree(np.asarray(xy_m, np.float64).reshape(-1, 2)) if len(xy_m) else None
        )


def transfer_objects(
    range_m: np.ndarray,
    bearing_rad: np.ndarray,
    T_kfsonar_framesonar: list[np.ndarray],
    keyframe_objects: list[KeyframeObjectPoints],
    eps_m: float,
    min_samples: int,
    min_features: int,
    match_radius_m: float,
) -> np.ndarray:
    """(n,) object id of each horizontal return of a submap frame, -1 for none.

    Args:
        range_m, bearing_rad: (n,) the frame's horizontal returns.
        T_kfsonar_framesonar: (4, 4) pose of the frame's horizontal sonar in each
            candidate keyframe's horizontal sonar frame.
        keyframe_objects: the candidate keyframes' object returns, same order.
        eps_m, min_samples, min_features: the classifier's clustering.
        match_radius_m: a return lies on an object within this of one of its returns.
    """
    n = len(range_m)
    out = np.full(n, -1, np.int64)
    if n == 0:
        return out
    xy = fan_to_xy(range_m, bearing_rad)
    cluster = cluster_features(xy, eps_m, min_samples, min_features)
    if (cluster < 0).all():
        return out
    clustered = np.flatnonzero(cluster >= 0)
    # Only clustered returns vote; noise stays unassigned whatever it lies on.
    best_d = np.full(clustered.size, np.inf)
    match = np.full(clustered.size, -1, np.int64)
    xy_clustered = xy[clustered]
    for T, objs in zip(T_kfsonar_framesonar, keyframe_objects, strict=True):
        if objs.tree is None:
            continue
        moved = xy_clustered @ T[:2, :2].T + T[:2, 3]
        d, i = objs.tree.query(moved, distance_upper_bound=match_radius_m)
        better = np.isfinite(d) & (d < best_d)
        best_d[better] = d[better]
        match[better] = objs.object_id[i[better]]
    voted = match >= 0
    if not voted.any():
        return out
    # Majority object per cluster (ties: the smaller object id), counted over one int64
    # code per (cluster, object) pair: sorted codes sort by cluster, then object.
    objects, object_code = np.unique(match[voted], return_inverse=True)
    codes, counts = np.unique(
        cluster[clustered[voted]] * objects.size + object_code.reshape(-1), return_counts=True
    )
    pair_cluster, pair_object = np.divmod(codes, objects.size)
    order = np.lexsort((pair_object, -counts, pair_cluster))
    first = np.r_[True, pair_cluster[order][1:] != pair_cluster[order][:-1]]
    winner = np.full(int(cluster.max()) + 1, -1, np.int64)
    winner[pair_cluster[order][first]] = objects[pair_object[order][first]]
    out[clustered] = winner[cluster[clustered]]
    return out
