"""Clustering of one frame's horizontal features into objects (paper Sec. IV.C): DBSCAN
in the fan plane, shared by stage `classify` (keyframes) and stage `submaps` (the frames
between them, with the same parameters: `sonarmap.stages.classify.stage.clustering`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from sonarmap.stages.kernels.lazy import lazy

spatial = lazy("scipy.spatial")
sparse = lazy("scipy.sparse")
csgraph = lazy("scipy.sparse.csgraph")
sk_cluster = lazy("sklearn.cluster")

__all__ = ["MAX_COUNT", "MAX_EPS_M", "cluster_features", "clustering", "clustering_params"]

CLUSTERING_NAMES = ("eps_m", "min_samples", "min_features")

MAX_EPS_M = 100.0
MAX_COUNT = 100_000
"""Bounds of the clustering parameters (those of `ClassifyConfig`'s overrides)."""


def clustering_params(eps_m: object, min_samples: object, min_features: object) -> dict[str, Any]:
    """`eps_m`, `min_samples`, `min_features` checked: 0 < eps_m <= MAX_EPS_M [m] and
    whole counts in 1..MAX_COUNT.

    Raises:
        ValueError: a value of another type or outside its bounds (a short prefix quoted).
    """
    out: dict[str, Any] = {}
    for name, value, kind in (
        ("eps_m", eps_m, float),
        ("min_samples", min_samples, int),
        ("min_features", min_features, int),
    ):
        number = value if isinstance(value, int | float) and not isinstance(value, bool) else None
        if number is None or not np.isfinite(number) or (kind is int and number != int(number)):
            what = "a number" if kind is float else "an integer"
            raise ValueError(f"{name} must be {what}, got {str(value)[:30]!r}")
        low, high = (0.0, MAX_EPS_M) if kind is float else (1, MAX_COUNT)
        if not (low < number <= high if kind is float else low <= number <= high):
            raise ValueError(f"{name} {number:g} outside ({low:g}, {high:g}]")
        out[name] = kind(number)
    return out


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


_RADIX_POINTS = 1 << 16
"""Up to this many points, a point index fits 16 bits (numpy radix-sorts those)."""


def _linked_components(xy_m: np.ndarray, eps_m: float, min_samples: int) -> np.ndarray:
    """DBSCAN for min_samples <= 2, as connected components of the eps-neighbour graph.

    With min_samples 2 every point with a neighbour within eps is a core point, so each
    cluster is a connected component and the isolated points are noise (min_samples 1:
    they are singleton clusters). Same partition as scikit-learn's DBSCAN, at a fraction of
    its overhead (docs/decisions/010-dbscan-as-linked-components.md).
    """
    n = len(xy_m)
    pairs = spatial.cKDTree(xy_m).query_pairs(eps_m, output_type="ndarray")
    # CSR rows straight from the pairs, grouped by their first point: components need no
    # sorted column indices, and sorting them (COO -> CSR) was most of the cost.
    indptr = np.zeros(n + 1, np.int32)
    np.cumsum(np.bincount(pairs[:, 0], minlength=n), out=indptr[1:])
    # Any order within a row will do: a stable sort of 16-bit keys is a radix sort, 5x
    # faster than the default quicksort of int64 keys on a frame's ~40k pairs.
    keys = pairs[:, 0].astype(np.uint16) if n <= _RADIX_POINTS else pairs[:, 0]
    neighbours = pairs[np.argsort(keys, kind="stable"), 1].astype(np.int32)
    graph = sparse.csr_matrix((np.ones(len(pairs)), neighbours, indptr), (n, n))
    _, comp = csgraph.connected_components(graph, directed=True, connection="weak")
    if min_samples == 2:
        isolated = np.bincount(comp, minlength=n)[comp] == 1
        comp = np.where(isolated, -1, comp)
    return comp.astype(np.int64)


def clustering(overrides: object, settings: object) -> dict[str, Any]:
    """`eps_m`, `min_samples`, `min_features`: each the override's (classify's config)
    unless None, else the model file's (`sonarmap.schemas.model_settings.ModelSettings` or its
    dict), checked by `clustering_params`; stage `classify` writes them as its output
    `clustering`, so stage `submaps` clusters its frames the same way.

    Raises:
        ValueError: neither gives one, or a value is out of bounds.
    """

    def model_value(name: str) -> object:
        if isinstance(settings, Mapping):
            return settings.get(name)
        return getattr(settings, name, None)

    picked = {
        n: model_value(n) if getattr(overrides, n) is None else getattr(overrides, n)
        for n in CLUSTERING_NAMES
    }
    for name in (n for n in CLUSTERING_NAMES if picked[n] is None):
        raise ValueError(f"the model file has no {name!r}; set classify.{name}")
    return clustering_params(**picked)
