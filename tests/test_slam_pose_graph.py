"""Vectorised SE(2) algebra against GTSAM's Pose2, and the iSAM2 wrapper."""

from __future__ import annotations

import gtsam
import numpy as np

from stages.pose_graph import (
    PlanarPoseGraph,
    se2_adjoint,
    se2_between,
    se2_compose,
    se2_inverse,
    se2_log,
)


def _poses(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform([-10, -10, -np.pi], [10, 10, np.pi], (n, 3))


def _vec(p: gtsam.Pose2) -> np.ndarray:
    return np.array([p.x(), p.y(), p.theta()])


def test_se2_helpers_match_gtsam() -> None:
    a, b = _poses(20, 0), _poses(20, 1)
    for i in range(20):
        pa, pb = gtsam.Pose2(*a[i]), gtsam.Pose2(*b[i])
        np.testing.assert_allclose(se2_compose(a[i], b[i]), _vec(pa.compose(pb)), atol=1e-9)
        np.testing.assert_allclose(se2_between(a[i], b[i]), _vec(pa.between(pb)), atol=1e-9)
        np.testing.assert_allclose(se2_inverse(a[i]), _vec(pa.inverse()), atol=1e-9)
        np.testing.assert_allclose(se2_log(a[i]), gtsam.Pose2.Logmap(pa), atol=1e-9)
        np.testing.assert_allclose(se2_adjoint(a[i]), pa.AdjointMap(), atol=1e-9)
    np.testing.assert_allclose(se2_log(np.array([1.0, 2.0, 0.0])), [1.0, 2.0, 0.0])


def test_isam2_closes_a_square_with_a_loop() -> None:
    graph = PlanarPoseGraph()
    cov = np.diag([0.01, 0.01, 1e-3])
    graph.add_pose(0, np.zeros(3))
    graph.add_prior(0, np.zeros(3), cov * 0.01)
    graph.update()
    step = np.array([2.0, 0.0, np.pi / 2])
    drift = np.array([0.05, 0.02, 0.03])
    for k in range(1, 5):
        graph.add_pose(k, se2_compose(graph.pose(k - 1), se2_compose(step, drift)))
        graph.add_between(k - 1, k, se2_compose(step, drift), cov)
        graph.update()
    before = graph.marginal_covariance(4)
    graph.add_between(0, 4, np.zeros(3), cov * 0.01)
    graph.update(extra_iterations=2)
    poses = graph.poses()
    assert poses.shape == (5, 3)
    assert np.linalg.norm(poses[4, :2]) < 0.02
    assert np.linalg.det(graph.marginal_covariance(4)) < 0.1 * np.linalg.det(before)
