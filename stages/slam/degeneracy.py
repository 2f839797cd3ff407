"""Which directions of SE(2) a scan match constrains, and a covariance that says so.

Point-to-point ICP always looks well constrained in translation (every pair pulls in both
axes), so its covariance hides the classic failure of scan matching: along a straight
wall, or a canal's two parallel walls, the scans fit equally well wherever they slide
along it. The point-to-line information does not hide it: each pair constrains the
motion only along the target surface's normal n, its Jacobian with respect to a
body-frame perturbation of the source pose is ``n^T R [I | (-p_y, p_x)]``, and
``H = sum J^T J`` has a (near) zero eigenvalue along every direction the geometry leaves
free (Zhang, Kaess & Singh, ICRA 2016, "On degeneracy of optimization-based state
estimation problems"; X-ICP, Tuna et al., T-RO 2023).

The yardstick is the odometry: with `reference` the (3, 3) covariance of one keyframe
step of the navigation (`SlamConfig.odom_chain_sigma_xy_m`, `odom_sigma_yaw_deg`), the
generalised eigenvalues mu of (H / sigma^2, reference^-1) compare, direction by direction,
what the scans pin down with what the navigation already knows (unit-free: metres and
radians are weighed by the navigation's own noise). sigma is the pairs' RMS distance, at
least the ICP covariance's 5 cm, and every pair counts as independent, so mu is the most
the geometry could give. A direction with mu < `min_ratio` (1: the scans constrain it
less than one step of odometry does, even at best) is degenerate: ICP's answer there is
where it stopped sliding, not a measurement.

A degenerate direction's variance is raised by `FREE_M2` (in the navigation-whitened
coordinates) in the factor's covariance, so the factor says nothing along it and the
odometry carries that direction alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

__all__ = ["FREE_M2", "Degeneracy", "constrained_covariance", "degeneracy", "surface_normals"]

FREE_M2 = 1e6
"""Variance, in units of the reference's variance, added along a degenerate direction."""

_SIGMA_FLOOR_M = 0.05
"""Least RMS pair distance assumed (`sonarmap.stages.slam.scan_matching.icp_covariance`'s)."""

_AXES = ("x", "y", "yaw")

_NORMAL_NEIGHBOURS = 6
"""Target points whose spread gives a surface normal (the point and its 5 nearest)."""


@dataclass(frozen=True)
class Degeneracy:
    """Eigen-analysis of a match's point-to-line information against the odometry's.

    Attributes:
        ratios: (3,) generalised eigenvalues mu, ascending (see the module docstring).
        directions: (3, 3) columns: each eigenvector as a tangent direction (x, y, yaw),
            scaled by the reference's standard deviations (navigation-whitened).
        whitened: (3, 3) columns: the eigenvectors in navigation-whitened coordinates.
        degenerate: (3,) bool per eigenvector.
    """

    ratios: np.ndarray
    directions: np.ndarray
    whitened: np.ndarray
    degenerate: np.ndarray

    @property
    def count(self) -> int:
        return int(self.degenerate.sum())

    @property
    def label(self) -> str:
        """The degenerate directions by their dominant axis in whitened coordinates (body
        frame of the source: x forward, y to port, yaw), comma-separated; "" when none."""
        names = {
            _AXES[int(np.argmax(np.abs(v)))]
            for v, d in zip(self.whitened.T, self.degenerate, strict=True)
            if d
        }
        return ",".join(a for a in _AXES if a in names)


def surface_normals(target: np.ndarray, tree: cKDTree, rows: np.ndarray) -> np.ndarray:
    """(M, 2) unit normals of the target surface at target points `rows`: the minor axis
    of the scatter of each point and its nearest neighbours (closed-form 2x2 eigenvector)."""
    k = min(_NORMAL_NEIGHBOURS, len(target))
    _, nn = tree.query(target[rows], k=k)
    near = target[np.asarray(nn).reshape(len(rows), k)]
    d = near - near.mean(axis=1, keepdims=True)
    cxx, cyy = (d[..., 0] ** 2).sum(axis=1), (d[..., 1] ** 2).sum(axis=1)
    cxy = (d[..., 0] * d[..., 1]).sum(axis=1)
    major = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)  # direction of largest spread
    return np.stack([-np.sin(major), np.cos(major)], axis=1)


def degeneracy(
    source: np.ndarray,
    target: np.ndarray,
    tree: cKDTree,
    pose: np.ndarray,
    radius_m: float,
    reference: np.ndarray,
    min_ratio: float = 1.0,
) -> Degeneracy:
    """Point-to-line information of `source` (N, 2) registered at `pose` (3,) on `target`
    (M, 2) with its k-d tree, over pairs closer than `radius_m`, against the (3, 3)
    `reference` covariance (diagonal: one odometry step); directions with mu < `min_ratio`
    are degenerate (all three with under 3 pairs)."""
    whiten = np.sqrt(np.diag(reference))
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, -s], [s, c]])
    moved = source @ rot.T + pose[:2]
    dist, rows = tree.query(moved, distance_upper_bound=radius_m)
    inlier = np.isfinite(dist)
    if inlier.sum() < 3:
        eye = np.eye(3)
        return Degeneracy(np.zeros(3), eye * whiten[:, None], eye, np.ones(3, bool))
    p = source[inlier]
    sigma2 = max(float(np.mean(dist[inlier] ** 2)), _SIGMA_FLOOR_M**2)
    nr = surface_normals(target, tree, rows[inlier]) @ rot  # n^T R, per pair
    jac = np.column_stack([nr, nr[:, 1] * p[:, 0] - nr[:, 0] * p[:, 1]]) * whiten
    ratios, vectors = np.linalg.eigh(jac.T @ jac / sigma2)
    return Degeneracy(ratios, vectors * whiten[:, None], vectors, ratios < min_ratio)


def constrained_covariance(cov: np.ndarray, found: Degeneracy) -> np.ndarray:
    """(3, 3) `cov` (body frame x, y, yaw) with the variance along each degenerate
    direction raised by `FREE_M2` times the reference's; unchanged when none is."""
    if not found.count:
        return cov
    free = found.directions[:, found.degenerate]
    return cov + FREE_M2 * free @ free.T
