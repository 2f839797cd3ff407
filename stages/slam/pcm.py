"""Pairwise consistency maximisation (PCM; Mangelson et al., ICRA 2018) for loop closures.

Two loop closures i: a -> b (measurement z_i) and j: c -> d (z_j) are pairwise consistent
when the cycle a -> c (odometry) -> d (loop j) -> b (odometry) -> a (loop i inverted)
closes within its uncertainty:

    e = Log((T_a^{-1} T_c) z_j (T_d^{-1} T_b) z_i^{-1}),   e^T S^{-1} e < chi2_{0.99}(3)

where S is the first-order covariance of the cycle: both loop covariances plus the
covariance of the two odometry segments, all moved into the world frame with SE(2)
adjoints (the test is invariant to that choice of frame). The accepted loops are a maximum
clique of the consistency graph (paper Sec. IV.A, "pairwise consistent measurement set
maximization").
"""

from __future__ import annotations

import numpy as np

from sonarmap.stages.kernels.lazy import lazy
from sonarmap.stages.slam.config import CHI2_99_3DOF
from sonarmap.stages.slam.pose_graph import (
    se2_adjoint,
    se2_between,
    se2_compose,
    se2_inverse,
    se2_log,
)

__all__ = [
    "CHI2_99_3DOF",
    "chain_covariance",
    "chi2_quantile",
    "invert_loops",
    "maximum_clique",
    "pairwise_consistency",
    "robust_noise_scale",
    "windowed_pcm",
]

special = lazy("scipy.special")


def chi2_quantile(probability: float, dof: int) -> float:
    """The chi-square quantile: scipy's `stats.chi2.ppf` to the bit (its own formula), from
    `scipy.special`, which imports in a fifth of the time `scipy.stats` takes."""
    return float(2.0 * special.gammaincinv(dof / 2.0, probability))


_EXACT_CLIQUE_LIMIT = 48
_PAIR_BLOCK = 100_000


def chain_covariance(poses: np.ndarray, edge_covs: np.ndarray) -> np.ndarray:
    """Cumulative world-frame covariance along an odometry chain 0 -> 1 -> ... -> N-1.

    Args:
        poses: (N, 3) poses (x_m, y_m, theta_rad) of the chain's nodes in the world frame.
        edge_covs: (N-1, 3, 3) covariance of edge k -> k+1 in the frame of node k+1.

    Returns:
        (N, 3, 3) prefix sums C with C[0] = 0: the covariance of the chain segment between
        nodes m < n, in the world frame, is ``C[n] - C[m]``.
    """
    ad = se2_adjoint(poses[1:])
    world = ad @ edge_covs @ np.swapaxes(ad, -1, -2)
    out = np.zeros((len(poses), 3, 3))
    out[1:] = np.cumsum(world, axis=0)
    return out


def _pair_chi2(
    poses: np.ndarray,
    chain_cov: np.ndarray,
    src: np.ndarray,
    dst: np.ndarray,
    z: np.ndarray,
    q_world: np.ndarray,
    i: np.ndarray,
    j: np.ndarray,
) -> np.ndarray:
    a, b, c, d = src[i], dst[i], src[j], dst[j]
    cycle = se2_compose(
        se2_compose(se2_between(poses[a], poses[c]), z[j]),
        se2_compose(se2_between(poses[d], poses[b]), se2_inverse(z[i])),
    )
    e_world = (se2_adjoint(poses[a]) @ se2_log(cycle)[..., None])[..., 0]
    seg1 = chain_cov[np.maximum(a, c)] - chain_cov[np.minimum(a, c)]
    seg2 = chain_cov[np.maximum(b, d)] - chain_cov[np.minimum(b, d)]
    s = q_world[i] + q_world[j] + seg1 + seg2
    return np.einsum("ni,ni->n", e_world, np.linalg.solve(s, e_world[..., None])[..., 0])


def pairwise_consistency(
    poses: np.ndarray,
    chain_cov: np.ndarray,
    src: np.ndarray,
    dst: np.ndarray,
    z: np.ndarray,
    cov: np.ndarray,
    threshold: float = CHI2_99_3DOF,
) -> np.ndarray:
    """Consistency graph of n loop closures (module docstring; vectorised over pairs).

    Args:
        poses: (N, 3) world poses of the nodes from odometry or the current estimate.
        chain_cov: (N, 3, 3) output of `chain_covariance` for the same nodes.
        src: (n,) int node index a of each loop.
        dst: (n,) int node index b of each loop.
        z: (n, 3) measured pose of b in the frame of a.
        cov: (n, 3, 3) measurement covariance (frame of b).
        threshold: chi-square gate on the cycle's Mahalanobis distance.

    Returns:
        (n, n) bool symmetric adjacency, False on the diagonal.
    """
    n = len(src)
    adjacency = np.zeros((n, n), dtype=bool)
    if n < 2:
        return adjacency
    ad_b = se2_adjoint(poses[dst])
    q_world = ad_b @ cov @ np.swapaxes(ad_b, -1, -2)
    iu, ju = np.triu_indices(n, 1)
    for start in range(0, len(iu), _PAIR_BLOCK):
        i, j = iu[start : start + _PAIR_BLOCK], ju[start : start + _PAIR_BLOCK]
        ok = _pair_chi2(poses, chain_cov, src, dst, z, q_world, i, j) < threshold
        adjacency[i[ok], j[ok]] = True
    return adjacency | adjacency.T


def robust_noise_scale(
    poses: np.ndarray,
    chain_cov: np.ndarray,
    src: np.ndarray,
    dst: np.ndarray,
    z: np.ndarray,
    cov: np.ndarray,
    quantile: float = 0.5,
) -> float:
    """Robust scale factor that calibrates the covariances of a graph (for PCM's gate).

    Each loop alone closes a cycle with the odometry chain, e_i = Log(T_a^{-1} T_b z_i^{-1});
    with calibrated covariances its Mahalanobis distance follows chi2(3), whose median is
    2.366. The median over all candidates (outliers included: they are a minority) divided
    by that value estimates how conservative the stated covariances are; multiply every
    covariance (odometry and loops) by it before `chain_covariance`/`pairwise_consistency`.

    Args:
        poses, chain_cov, src, dst, z, cov: as in `pairwise_consistency`.
        quantile: the quantile matched to chi2(3); the median is robust to up to half the
            candidates being outliers, higher quantiles are more conservative on
            heavy-tailed (drifting) odometry but tolerate fewer outliers.

    Returns:
        The scale (1.0 for calibrated covariances, < 1 for conservative ones).
    """
    e = se2_log(se2_compose(se2_between(poses[src], poses[dst]), se2_inverse(z)))
    e_world = (se2_adjoint(poses[src]) @ e[..., None])[..., 0]
    ad_b = se2_adjoint(poses[dst])
    s = ad_b @ cov @ np.swapaxes(ad_b, -1, -2)
    s = s + chain_cov[np.maximum(src, dst)] - chain_cov[np.minimum(src, dst)]
    d2 = np.einsum("ni,ni->n", e_world, np.linalg.solve(s, e_world[..., None])[..., 0])
    return float(np.quantile(d2, quantile) / chi2_quantile(quantile, 3))


def _exact_clique(adjacency: np.ndarray) -> list[int]:
    n = len(adjacency)
    neighbours = [sum(1 << int(k) for k in np.flatnonzero(adjacency[v])) for v in range(n)]
    best = [0, 0]  # mask, size

    def expand(r: int, r_size: int, p: int) -> None:
        while p:
            if r_size + p.bit_count() <= best[1]:
                return
            v = p.bit_length() - 1
            p &= ~(1 << v)
            q = p & neighbours[v]
            if q:
                expand(r | (1 << v), r_size + 1, q)
            elif r_size + 1 > best[1]:
                best[0], best[1] = r | (1 << v), r_size + 1

    expand(0, 0, (1 << n) - 1)
    return [v for v in range(n) if best[0] >> v & 1]


def _greedy_clique(adjacency: np.ndarray) -> list[int]:
    degree = adjacency.sum(axis=1)
    counts = adjacency.astype(np.int32)
    best: list[int] = []
    for v in np.argsort(-degree, kind="stable"):
        if degree[v] + 1 <= len(best):
            break
        clique = [int(v)]
        candidates = adjacency[v] & (degree >= len(best))
        inner = counts[:, candidates].sum(axis=1)
        while candidates.any():
            idx = np.flatnonzero(candidates)
            u = int(idx[np.argmax(inner[idx])])
            clique.append(u)
            removed = candidates & ~adjacency[u]
            candidates &= adjacency[u]
            inner -= counts[:, removed].sum(axis=1)
        if len(clique) > len(best):
            best = clique
    return best


def maximum_clique(adjacency: np.ndarray) -> np.ndarray:
    """A maximum clique of an undirected graph.

    Exact branch and bound (Carraghan-Pardalos) up to 48 vertices; above that a greedy
    heuristic after Pattabiraman et al. (2015): from each vertex in decreasing degree order,
    repeatedly add the candidate with most neighbours among the remaining candidates.

    Args:
        adjacency: (n, n) bool symmetric adjacency matrix.

    Returns:
        (k,) int64 sorted vertex indices of the clique (empty when n == 0).
    """
    adjacency = np.asarray(adjacency, dtype=bool)
    if len(adjacency) == 0:
        return np.zeros(0, dtype=np.int64)
    if len(adjacency) <= _EXACT_CLIQUE_LIMIT:
        clique = _exact_clique(adjacency)
    else:
        clique = _greedy_clique(adjacency)
    return np.sort(np.asarray(clique, dtype=np.int64))


def invert_loops(z: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reverse loop measurements: (n, 3) z -> z^{-1}, (n, 3, 3) covariance moved to the new frame.

    ``(z Exp(xi))^{-1} = z^{-1} Exp(-Ad_z xi)``, so the covariance becomes ``Ad_z S Ad_z^T``.
    """
    ad = se2_adjoint(z)
    return se2_inverse(z), ad @ cov @ np.swapaxes(ad, -1, -2)


def windowed_pcm(
    poses: np.ndarray,
    chain_cov: np.ndarray,
    src: np.ndarray,
    dst: np.ndarray,
    z: np.ndarray,
    cov: np.ndarray,
    window_keys: int = 5,
    min_clique: int = 2,
    threshold: float = CHI2_99_3DOF,
) -> np.ndarray:
    """PCM as the SLAM front end runs it: candidates arrive in order of their source node.

    On each arrival the queue (candidates whose source node lies within `window_keys` of the
    newest) is tested pairwise and its maximum clique, if it has at least `min_clique`
    members, is accepted (acceptance is final). Short windows keep the odometry segments of
    every tested cycle short, where a random-walk noise model still holds.

    Args:
        poses, chain_cov, src, dst, z, cov: as in `pairwise_consistency`; the source node of
            a loop is the newer pose (`src`), use `invert_loops` to orient loops that way.
        window_keys: queue length in source nodes (the authors' `pcm_queue_size`, 5).
        min_clique: smallest clique that is accepted (the authors' `min_pcm`, 2).
        threshold: chi-square gate.

    Returns:
        (n,) bool, True for accepted loops.
    """
    order = np.argsort(src, kind="stable")
    accepted = np.zeros(len(src), dtype=bool)
    for k in range(len(order)):
        newest = src[order[k]]
        arrived = order[: k + 1]
        queue = arrived[src[arrived] >= newest - window_keys]
        adjacency = pairwise_consistency(
            poses, chain_cov, src[queue], dst[queue], z[queue], cov[queue], threshold
        )
        clique = maximum_clique(adjacency)
        if len(clique) >= min_clique:
            accepted[queue[clique]] = True
    return accepted
