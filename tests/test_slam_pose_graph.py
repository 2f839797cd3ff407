"""Vectorised SE(2) algebra against GTSAM's Pose2, and the iSAM2 wrapper."""

from __future__ import annotations

import gtsam
import numpy as np

from sonarmap.stages.slam.pose_graph import (
    PlanarPoseGraph,
    se2_adjoint,
    se2_between,
    se2_compose,
    se2_inverse,
    se2_log,
    wrap_angle,
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


def _loop_course(n: int) -> np.ndarray:
    """True poses: a 2 m-step course around a 30 m x 20 m racetrack, twice."""
    t = np.linspace(0, 4 * np.pi, n)
    yaw = np.unwrap(np.arctan2(20 * np.cos(t), -30 * np.sin(t)))
    return np.column_stack([15 * np.cos(t), 10 * np.sin(t), yaw])


def _solve_with_headings(biased: bool) -> tuple[np.ndarray, np.ndarray, PlanarPoseGraph]:
    """Odometry + loops + headings whose bias ramps by 3 deg over the course."""
    rng = np.random.default_rng(4)
    truth = _loop_course(80)
    n = len(truth)
    bias = np.deg2rad(np.linspace(0.0, 3.0, n))
    heading = truth[:, 2] - bias + rng.normal(0, np.deg2rad(0.3), n)
    graph = PlanarPoseGraph()
    graph.add_pose(0, truth[0])
    graph.add_prior(0, truth[0], np.diag([1e-4, 1e-4, 1e-6]))
    graph.update()
    odo_cov = np.diag([0.02**2, 0.02**2, np.deg2rad(0.3) ** 2])
    loop_cov = np.diag([0.05**2, 0.05**2, np.deg2rad(0.2) ** 2])
    for k in range(1, n):
        step = se2_between(truth[k - 1], truth[k]) + rng.normal(0, [0.02, 0.02, 0.005])
        graph.add_pose(k, se2_compose(graph.pose(k - 1), step))
        graph.add_between(k - 1, k, step, odo_cov)
        nav = np.array([truth[k, 0], truth[k, 1], heading[k]])
        if biased:
            guess = 0.0 if k == 1 else graph.bias(k - 1)
            graph.add_biased_heading(k, nav, np.deg2rad(0.5), np.deg2rad(0.1), guess, 0.1)
        else:
            graph.add_prior(k, nav, np.diag([1e6, 1e6, np.deg2rad(0.5) ** 2]))
        if k >= 40:  # the second lap closes loops on the first
            graph.add_between(k - 40, k, se2_between(truth[k - 40], truth[k]), loop_cov)
        graph.update()
    return graph.poses(), truth, graph


def test_heading_bias_states_let_loops_correct_a_wandering_compass() -> None:
    """Independent heading priors pull the yaw toward the compass, bias and all; with a
    random-walk bias state per heading the loops observe the bias and the yaw follows
    them. The estimated biases reproduce the ramp."""
    plain, truth, _ = _solve_with_headings(biased=False)
    with_bias, _, graph = _solve_with_headings(biased=True)
    yaw_error = {
        name: np.rad2deg(np.sqrt(np.mean(wrap_angle(est[:, 2] - truth[:, 2]) ** 2)))
        for name, est in (("plain", plain), ("biased", with_bias))
    }
    assert yaw_error["plain"] > 0.8, yaw_error  # pulled toward the 0-3 deg bias
    assert yaw_error["biased"] < 0.4 * yaw_error["plain"], yaw_error
    bias = np.rad2deg([graph.bias(k) for k in range(1, len(truth))])
    np.testing.assert_allclose(bias, np.linspace(0.0, 3.0, len(truth))[1:], atol=0.6)
    assert len(with_bias) == len(truth)  # bias variables are not poses


def test_scaled_odometry_jacobians_match_finite_differences() -> None:
    graph = PlanarPoseGraph()
    graph.add_pose(0, np.array([1.0, 2.0, 0.3]))
    graph.add_pose(1, np.array([2.5, 2.9, 0.5]))
    graph.add_odometry_scale(0.02, np.array([0.01, -0.02]))
    graph.add_scaled_odometry(0, 1, np.array([1.7, 0.3, 0.25]), np.eye(3))
    factor = graph._graph.at(graph._graph.size() - 1)
    values = graph._values
    analytic, _ = factor.linearize(values).jacobian()
    e0, eps, numeric = factor.unwhitenedError(values), 1e-6, []
    for key, dim in (
        (gtsam.symbol("x", 0), 3),
        (gtsam.symbol("x", 1), 3),
        (gtsam.symbol("s", 0), 2),
    ):
        for d in range(dim):
            moved = gtsam.Values(values)
            delta = np.zeros(dim)
            delta[d] = eps
            if dim == 3:
                moved.update(key, values.atPose2(key).compose(gtsam.Pose2.Expmap(delta)))
            else:
                moved.update(key, np.asarray(values.atPoint2(key)) + delta)
            numeric.append((factor.unwhitenedError(moved) - e0) / eps)
    np.testing.assert_allclose(analytic, np.array(numeric).T, atol=1e-5)


def _solve_with_scale_error(scale_state: bool) -> tuple[np.ndarray, np.ndarray, PlanarPoseGraph]:
    """Odometry that reads 3 % long along x (a DVL scale error), exact headings, and the
    second lap's loops on the first."""
    rng = np.random.default_rng(5)
    truth = _loop_course(80)
    graph = PlanarPoseGraph()
    graph.add_pose(0, truth[0])
    graph.add_prior(0, truth[0], np.diag([1e-4, 1e-4, 1e-6]))
    if scale_state:
        graph.add_odometry_scale(0.05)
    graph.update()
    odo_cov = np.diag([0.01**2, 0.01**2, np.deg2rad(0.3) ** 2])
    loop_cov = np.diag([0.05**2, 0.05**2, np.deg2rad(0.2) ** 2])
    for k in range(1, len(truth)):
        step = se2_between(truth[k - 1], truth[k])
        step = step * [1.03, 1.0, 1.0] + rng.normal(0, [0.01, 0.01, 0.002])
        graph.add_pose(k, se2_compose(graph.pose(k - 1), step))
        if scale_state:
            graph.add_scaled_odometry(k - 1, k, step, odo_cov)
        else:
            graph.add_between(k - 1, k, step, odo_cov)
        graph.add_prior(k, truth[k], np.diag([1e6, 1e6, np.deg2rad(0.3) ** 2]))
        if k >= 40:
            graph.add_between(k - 40, k, se2_between(truth[k - 40], truth[k]), loop_cov)
        graph.update()
    return graph.poses(), truth, graph


def test_odometry_scale_state_recovers_a_dvl_scale_error() -> None:
    """Per-step odometry noise cannot absorb a fixed scale error: the loops then pull
    against every step. With the scale as a state the loops observe it."""
    plain, truth, _ = _solve_with_scale_error(scale_state=False)
    scaled, _, graph = _solve_with_scale_error(scale_state=True)
    rmse = {
        name: float(np.sqrt(np.mean(np.sum((est[:, :2] - truth[:, :2]) ** 2, axis=1))))
        for name, est in (("plain", plain), ("scaled", scaled))
    }
    assert rmse["scaled"] < 0.3 * rmse["plain"], rmse
    assert abs(graph.scale()[0] - 0.03) < 0.003, graph.scale()
    assert abs(graph.scale()[1]) < 0.02, graph.scale()
