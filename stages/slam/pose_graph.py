"""Planar pose graph on GTSAM iSAM2, and vectorised SE(2) algebra on (x, y, theta) arrays.

The factor graph of paper Sec. IV.A (unnumbered equation): a prior on the first pose,
odometry factors, sequential scan-matching (SSM) factors and loop-closure (NSSM) factors,
all `BetweenFactorPose2` with Gaussian noise, solved incrementally with iSAM2. Beyond the
paper: heading factors through random-walk bias states (`add_biased_heading`, stock
factors) and odometry read through a per-mission scale error (`add_scaled_odometry`, a
`CustomFactor` with analytic Jacobians).

SE(2) conventions follow GTSAM's `Pose2`: a pose is (x_m, y_m, theta_rad), noise and
covariances are in the body frame with tangent order (x, y, theta) (right perturbation
``T Exp(xi)``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sonarmap.stages.kernels.lazy import lazy

gtsam = lazy("gtsam")

__all__ = [
    "PlanarPoseGraph",
    "se2_adjoint",
    "se2_between",
    "se2_compose",
    "se2_inverse",
    "se2_log",
    "wrap_angle",
]


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap angles [rad] into [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def se2_compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a * b`` for (..., 3) poses (x_m, y_m, theta_rad); broadcasts."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [
            a[..., 0] + c * b[..., 0] - s * b[..., 1],
            a[..., 1] + s * b[..., 0] + c * b[..., 1],
            wrap_angle(a[..., 2] + b[..., 2]),
        ],
        axis=-1,
    )


def se2_inverse(a: np.ndarray) -> np.ndarray:
    """``a^{-1}`` for (..., 3) poses."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [-(c * a[..., 0] + s * a[..., 1]), s * a[..., 0] - c * a[..., 1], -a[..., 2]], axis=-1
    )


def se2_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a^{-1} b``: pose b in the frame of a, for (..., 3) poses."""
    return se2_compose(se2_inverse(a), b)


def se2_log(a: np.ndarray) -> np.ndarray:
    """GTSAM's `Pose2.Logmap` for (..., 3) poses -> (..., 3) tangent vectors (x, y, theta)."""
    w = wrap_angle(a[..., 2])
    small = np.abs(w) < 1e-9
    ws = np.where(small, 1.0, w)
    sa = np.where(small, 1.0, np.sin(ws) / ws)
    sb = np.where(small, 0.5 * w, (1.0 - np.cos(ws)) / ws)
    det = sa * sa + sb * sb
    x, y = a[..., 0], a[..., 1]
    return np.stack([(sa * x + sb * y) / det, (-sb * x + sa * y) / det, w], axis=-1)


def se2_adjoint(a: np.ndarray) -> np.ndarray:
    """(..., 3, 3) adjoint maps of (..., 3) poses: ``T Exp(xi) = Exp(Ad_T xi) T``."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    out = np.zeros((*a.shape[:-1], 3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 0, 2] = c, -s, a[..., 1]
    out[..., 1, 0], out[..., 1, 1], out[..., 1, 2] = s, c, -a[..., 0]
    out[..., 2, 2] = 1.0
    return out


_FREE_M = 1e3
"""Std [m] of a factor's position part that is not measured."""

_BIAS_ANCHOR_M = 1.0
"""Std [m] holding a bias variable's unused position part at the origin."""


def _pose2(p: np.ndarray) -> gtsam.Pose2:
    return gtsam.Pose2(float(p[0]), float(p[1]), float(p[2]))


class PlanarPoseGraph:
    """Incremental Pose2 graph (iSAM2) keyed by keyframe index 0..K-1."""

    def __init__(self, relinearize_threshold: float = 0.01, relinearize_skip: int = 1) -> None:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(relinearize_threshold)
        params.relinearizeSkip = relinearize_skip
        self._isam = gtsam.ISAM2(params)
        self._graph = gtsam.NonlinearFactorGraph()
        self._values = gtsam.Values()
        self._estimate = gtsam.Values()
        self.size = 0
        self._biases: list[int] = []
        self._scale_key: int | None = None

    def add_pose(self, index: int, initial: np.ndarray) -> None:
        """Declare pose `index` (must be the next one) with an initial guess (3,)."""
        if index != self.size:
            raise ValueError(f"poses must be added in order: expected {self.size}, got {index}")
        self._values.insert(gtsam.symbol("x", index), _pose2(initial))
        self.size += 1

    def add_prior(self, index: int, pose: np.ndarray, cov: np.ndarray) -> None:
        """Prior factor on pose `index` with (3, 3) covariance (body frame)."""
        noise = gtsam.noiseModel.Gaussian.Covariance(np.asarray(cov, dtype=np.float64))
        self._graph.add(gtsam.PriorFactorPose2(gtsam.symbol("x", index), _pose2(pose), noise))

    def add_between(
        self,
        i: int,
        j: int,
        z: np.ndarray,
        cov: np.ndarray,
        cauchy_k: float | None = None,
        huber_k: float | None = None,
    ) -> None:
        """Between factor: pose j measured in the frame of pose i, (3, 3) covariance.

        `cauchy_k` wraps the Gaussian in a Cauchy M-estimator with that scale (in units of
        the whitened error): a residual of k sigma weighs half as much as under the Gaussian.
        `huber_k` (when `cauchy_k` is None): a Huber M-estimator, quadratic within k sigma,
        linear beyond.
        """
        noise = gtsam.noiseModel.Gaussian.Covariance(np.asarray(cov, dtype=np.float64))
        if cauchy_k is not None:
            noise = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Cauchy.Create(cauchy_k), noise
            )
        elif huber_k is not None:
            noise = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Huber.Create(huber_k), noise
            )
        self._graph.add(
            gtsam.BetweenFactorPose2(gtsam.symbol("x", i), gtsam.symbol("x", j), _pose2(z), noise)
        )

    def add_biased_heading(
        self,
        index: int,
        pose: np.ndarray,
        sigma_rad: float,
        walk_sigma_rad: float,
        bias_guess_rad: float,
        first_sigma_rad: float,
    ) -> None:
        """Absolute heading measurement of pose `index` through a slowly varying bias.

        A compass or AHRS heading is the true yaw plus a bias that wanders (a random walk)
        plus white noise: h_k = yaw_k - b_k + n_k, b_k - b_{k-1} ~ N(0, walk_sigma^2). Each
        measured pose gets a bias variable B_k = Pose2(0, 0, b_k), chained to the previous
        one by the walk; the measurement is a between factor B_k -> X_k whose rotation is
        yaw_k - b_k (its position part is left free). Without the bias states, independent
        heading priors pin the trajectory to the wandering bias.

        Args:
            index: the pose; pose: (3,) the navigation pose (x, y, heading h).
            sigma_rad: white noise of the heading; walk_sigma_rad: std of the bias change
                since the previous measured pose; bias_guess_rad: initial value of b_k.
            first_sigma_rad: prior std of the first bias (its gauge; the constant part of
                the bias is not observable from relative measurements).
        """
        key = gtsam.symbol("b", index)
        self._values.insert(key, gtsam.Pose2(0.0, 0.0, float(bias_guess_rad)))
        anchor = np.array([_BIAS_ANCHOR_M, _BIAS_ANCHOR_M])
        if not self._biases:
            noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([*anchor, first_sigma_rad]))
            self._graph.add(gtsam.PriorFactorPose2(key, gtsam.Pose2(0.0, 0.0, 0.0), noise))
        else:
            noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([*anchor, walk_sigma_rad]))
            previous = gtsam.symbol("b", self._biases[-1])
            self._graph.add(gtsam.BetweenFactorPose2(previous, key, gtsam.Pose2(), noise))
        self._biases.append(index)
        # B^-1 X: rotation yaw - b, position R(-b) t_X; the position is not measured.
        c, s = np.cos(bias_guess_rad), np.sin(bias_guess_rad)
        z = np.array([c * pose[0] + s * pose[1], -s * pose[0] + c * pose[1], pose[2]])
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([_FREE_M, _FREE_M, sigma_rad]))
        self._graph.add(gtsam.BetweenFactorPose2(key, gtsam.symbol("x", index), _pose2(z), noise))

    def add_odometry_scale(self, sigma: float, guess: np.ndarray | None = None) -> None:
        """Declare the odometry's scale error s = (s_x, s_y) (one per mission), prior N(0, sigma^2).

        A DVL's per-axis scale error is fixed over a mission; folded into independent
        per-step noise it would need a step noise several times the real one (which then
        lets biased loop closures bend good stretches of track). See `add_scaled_odometry`.
        """
        if self._scale_key is not None:
            raise ValueError("pose graph: the odometry scale is already declared")
        self._scale_key = gtsam.symbol("s", 0)
        start = np.zeros(2) if guess is None else np.asarray(guess, np.float64)
        self._values.insert(self._scale_key, gtsam.Point2(float(start[0]), float(start[1])))
        noise = gtsam.noiseModel.Isotropic.Sigma(2, float(sigma))
        self._graph.add(gtsam.PriorFactorPoint2(self._scale_key, gtsam.Point2(0.0, 0.0), noise))

    def add_scaled_odometry(self, i: int, j: int, z: np.ndarray, cov: np.ndarray) -> None:
        """Odometry from pose i to pose j measured with the scale error `add_odometry_scale`.

        The dead-reckoned motion z = (z_x, z_y, z_theta) in the frame of pose i reads the
        true motion (t, theta) = X_i^-1 X_j as ((1 + s_x) t_x, (1 + s_y) t_y, theta) plus
        white noise of (3, 3) covariance `cov`. Error and Jacobians (right perturbations of
        both poses, GTSAM's Pose2 convention) are written out below.
        """
        if self._scale_key is None:
            raise ValueError("pose graph: add_odometry_scale first")
        zx, zy, zt = (float(v) for v in z)
        keys = [gtsam.symbol("x", i), gtsam.symbol("x", j), self._scale_key]

        def error(_factor: object, values: Any, jacobians: list | None) -> np.ndarray:
            xi = values.atPose2(keys[0])
            xj = values.atPose2(keys[1])
            scale = 1.0 + np.asarray(values.atPoint2(keys[2]), np.float64)
            rel = xi.between(xj)
            t = np.array([rel.x(), rel.y()])
            err = np.array(
                [scale[0] * t[0] - zx, scale[1] * t[1] - zy, wrap_angle(rel.theta() - zt)]
            )
            if jacobians is not None:
                c, s = np.cos(rel.theta()), np.sin(rel.theta())
                d_i = np.array([[-1.0, 0.0, t[1]], [0.0, -1.0, -t[0]], [0.0, 0.0, -1.0]])
                d_j = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
                weight = np.diag([scale[0], scale[1], 1.0])
                jacobians[0] = weight @ d_i
                jacobians[1] = weight @ d_j
                jacobians[2] = np.array([[t[0], 0.0], [0.0, t[1]], [0.0, 0.0]])
            return err

        noise = gtsam.noiseModel.Gaussian.Covariance(np.asarray(cov, dtype=np.float64))
        self._graph.add(gtsam.CustomFactor(noise, keys, error))

    def scale(self) -> np.ndarray:
        """Current estimate (2,) of the odometry scale error (s_x, s_y)."""
        if self._scale_key is None:
            return np.zeros(2)
        return np.asarray(self._estimate.atPoint2(self._scale_key), np.float64).copy()

    def bias(self, index: int) -> float:
        """Current estimate of the heading bias b of pose `index` [rad]."""
        return float(self._estimate.atPose2(gtsam.symbol("b", index)).theta())

    def update(self, extra_iterations: int = 0) -> None:
        """Push pending factors and values into iSAM2, then refresh the estimate."""
        self._isam.update(self._graph, self._values)
        for _ in range(extra_iterations):
            self._isam.update()
        self._graph = gtsam.NonlinearFactorGraph()
        self._values = gtsam.Values()
        self._estimate = self._isam.calculateEstimate()

    def poses(self) -> np.ndarray:
        """(K, 3) current estimate (x_m, y_m, theta_rad) of every pose, in key order."""
        if self.size == 0:
            return np.zeros((0, 3))
        every = np.asarray(gtsam.utilities.extractPose2(self._estimate), dtype=np.float64)
        # Values are ordered by key and symbol "b" (biases) sorts before "x" (poses).
        if len(every) != self.size + len(self._biases):
            raise RuntimeError("pose graph: unexpected Pose2 values in the estimate")
        return every[len(self._biases) :]

    def pose(self, index: int) -> np.ndarray:
        """(3,) current estimate of one pose."""
        p = self._estimate.atPose2(gtsam.symbol("x", index))
        return np.array([p.x(), p.y(), p.theta()])

    def marginal_covariance(self, index: int) -> np.ndarray:
        """(3, 3) marginal covariance of one pose (body frame, order x, y, theta)."""
        return np.asarray(self._isam.marginalCovariance(gtsam.symbol("x", index)))
