"""Pairwise consistency maximisation: cliques, consistency, and the real Intel graph."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from sonarmap.stages.slam.pcm import (
    chain_covariance,
    maximum_clique,
    pairwise_consistency,
    robust_noise_scale,
    windowed_pcm,
)
from sonarmap.stages.slam.pose_graph import se2_between, se2_compose
from tests.fixtures import intel_loops


def _is_clique(adjacency: np.ndarray, nodes: np.ndarray) -> bool:
    return all(adjacency[a, b] for a, b in itertools.combinations(nodes, 2))


def test_exact_maximum_clique_matches_brute_force() -> None:
    rng = np.random.default_rng(0)
    for n, density in [(6, 0.5), (9, 0.6), (11, 0.7), (12, 0.3)]:
        upper = np.triu(rng.random((n, n)) < density, 1)
        adjacency = upper | upper.T
        best = max(
            len(c)
            for r in range(1, n + 1)
            for c in itertools.combinations(range(n), r)
            if _is_clique(adjacency, np.array(c))
        )
        clique = maximum_clique(adjacency)
        assert len(clique) == best and _is_clique(adjacency, clique)


def test_greedy_clique_on_a_large_graph_finds_the_planted_clique() -> None:
    rng = np.random.default_rng(1)
    n = 200
    upper = np.triu(rng.random((n, n)) < 0.1, 1)
    planted = rng.choice(n, 40, replace=False)
    upper[np.ix_(planted, planted)] = True
    adjacency = np.triu(upper, 1)
    adjacency = adjacency | adjacency.T
    clique = maximum_clique(adjacency)
    assert _is_clique(adjacency, clique)
    assert set(planted.tolist()) <= set(clique.tolist())


def test_consistency_flags_the_loop_that_disagrees_with_odometry() -> None:
    steps = np.tile([1.0, 0.0, np.pi / 10], (20, 1))  # a circle of 20 poses
    poses = np.zeros((21, 3))
    for k, u in enumerate(steps):
        poses[k + 1] = se2_compose(poses[k], u)
    chain = chain_covariance(poses, np.tile(np.diag([0.01, 0.01, 1e-4]), (20, 1, 1)))
    src, dst = np.array([0, 1, 2, 3]), np.array([20, 19, 18, 17])
    z = se2_between(poses[src], poses[dst])
    z[3] = se2_compose(z[3], np.array([1.5, -1.0, 0.2]))  # a false loop
    cov = np.tile(np.diag([0.01, 0.01, 1e-4]), (4, 1, 1))
    adjacency = pairwise_consistency(poses, chain, src, dst, z, cov)
    assert adjacency[:3, :3][np.triu_indices(3, 1)].all()
    assert not adjacency[3].any()
    np.testing.assert_array_equal(maximum_clique(adjacency), [0, 1, 2])


def test_pcm_on_intel_rejects_injected_false_loops(shared_data: Path) -> None:
    s = intel_loops(shared_data / "posegraphs" / "intel.g2o")
    poses, odo_cov, src, dst, z, cov, truth = s.poses, s.odo_cov, s.src, s.dst, s.z, s.cov, s.truth
    # the file's information matrices are ~1000x too conservative: calibrate their scale
    scale = robust_noise_scale(poses, chain_covariance(poses, odo_cov), src, dst, z, cov, 0.75)
    assert scale < 0.01
    chain = chain_covariance(poses, odo_cov * scale)
    accepted = windowed_pcm(poses, chain, src, dst, z, cov * scale, window_keys=20)
    kept, rejected = accepted[truth].mean(), 1.0 - accepted[~truth].mean()
    assert rejected >= 0.95, rejected
    assert kept >= 0.90, kept


def test_chi2_constant_matches_scipy() -> None:
    from scipy.stats import chi2

    from sonarmap.stages.slam.pcm import CHI2_99_3DOF

    assert abs(CHI2_99_3DOF - chi2.ppf(0.99, 3)) < 1e-9


def test_chi2_quantile_is_scipy_stats_to_the_bit() -> None:
    from scipy.stats import chi2

    from sonarmap.stages.slam.pcm import chi2_quantile

    for p in (0.5, 0.9, 0.95, 0.99, 0.999):
        for dof in (1, 2, 3):
            assert chi2_quantile(p, dof) == chi2.ppf(p, dof)
