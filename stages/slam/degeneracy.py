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

Only translation is tested: the heading factors of the AHRS keep yaw. The yaw is first
marginalised out (the Schur complement of H), since a rotation about a far point also
slides a wall; the 2 x 2 translation information left has eigenvalues l_min <= l_max (both
m^-2: no unit to choose) and the direction of l_min is degenerate when l_min / l_max <
`min_ratio`: the surface normals' component along it is, in RMS, under sqrt(min_ratio)
of that along the best one (0.05: about sin 13 deg; a wall's corrugation, or two walls
at a shallow angle, stay below it). The normals are those of the structure, not of its
returns' scatter: the minor axis of each paired target point's 40 nearest neighbours
(about 10 m of wall in the keyframe clouds' 0.25 m voxels).

A degenerate direction's variance is raised by `FREE_M2` in the factor's covariance, so
the factor says nothing along it and the odometry carries that direction alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

__all__ = ["FREE_M2", "Degeneracy", "constrained_covariance", "degeneracy", "surface_normals"]

FREE_M2 = 1e6
"""Variance [m^2] added along a degenerate direction."""

_NORMAL_NEIGHBOURS = 40
"""Target points whose spread gives a surface normal (see the module docstring)."""


@dataclass(frozen=True)
class Degeneracy:
    """Eigen-analysis of a match's point-to-line translation information.

    Attributes:
        ratio: l_min / l_max of the translation information, yaw marginalised (0 when
            there are no pairs).
        direction: (2,) unit vector of l_min, body frame of the source (x forward, y port).
        degenerate: whether the match leaves that direction unconstrained.
        extent_m: length of the paired source points along `direction` [m].
    """

    ratio: float
    direction: np.ndarray
    degenerate: bool
    extent_m: float = 0.0

    @property
    def count(self) -> int:
        return int(self.degenerate)

    @property
    def label(self) -> str:
        """ "x" or "y", the body axis nearest the degenerate direction; "" when none."""
        if not self.degenerate:
            return ""
        return "x" if abs(self.direction[0]) >= abs(self.direction[1]) else "y"


def surface_normals(target: np.ndarray, tree: cKDTree, rows: np.ndarray) -> np.ndarray:
    """(M, 2) unit normals of the target surface at target points `rows`: the minor axis
    of the scatter of each point and its nearest neighbours (closed-form 2x2 eigenvector).
    Each distinct row is computed once (many source points pair with the same target)."""
    unique, inverse = np.unique(rows, return_inverse=True)
    k = min(_NORMAL_NEIGHBOURS, len(target))
    _, nn = tree.query(target[unique], k=k)
    nn = np.asarray(nn).reshape(len(unique), k)
    x, y = target[nn, 0], target[nn, 1]
    mx, my = x.mean(axis=1, keepdims=True), y.mean(axis=1, keepdims=True)
    x, y = x - mx, y - my
    cxx, cyy, cxy = (
        np.einsum("ij,ij->i", x, x),
        np.einsum("ij,ij->i", y, y),
        np.einsum("ij,ij->i", x, y),
    )
    major = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)  # direction of largest spread
    return np.stack([-np.sin(major), np.cos(major)], axis=1)[inverse.reshape(-1)]


def degeneracy(
    source: np.ndarray,
    target: np.ndarray,
    tree: cKDTree,
    pose: np.ndarray,
    radius_m: float,
    min_ratio: float,
) -> Degeneracy:
    """Point-to-line translation information of `source` (N, 2) registered at `pose` (3,)
    on `target` (M, 2) with its k-d tree, over pairs closer than `radius_m`; its weakest
    direction is degenerate when l_min / l_max < `min_ratio` (and with under 3 pairs)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, -s], [s, c]])
    dist, rows = tree.query(source @ rot.T + pose[:2], distance_upper_bound=radius_m)
    inlier = np.isfinite(dist)
    if inlier.sum() < 3:
        return Degeneracy(0.0, np.array([1.0, 0.0]), True)
    p = source[inlier]
    nr = surface_normals(target, tree, rows[inlier]) @ rot  # n^T R, per pair
    jac = np.column_stack([nr, nr[:, 1] * p[:, 0] - nr[:, 0] * p[:, 1]])
    h = jac.T @ jac
    # Yaw marginalised (Schur complement); a yaw nothing constrains leaves h[:2, :2].
    cross = h[:2, 2:] @ h[2:, :2] / h[2, 2] if h[2, 2] > 0 else 0.0
    values, vectors = np.linalg.eigh(h[:2, :2] - cross)
    ratio = float(values[0] / values[1]) if values[1] > 0 else 0.0
    along = p @ vectors[:, 0]
    extent = float(along.max() - along.min())
    return Degeneracy(ratio, vectors[:, 0], ratio < min_ratio, extent)


def constrained_covariance(
    cov: np.ndarray, found: Degeneracy, translation_m: np.ndarray | None = None, tilt: float = 0.0
) -> np.ndarray:
    """(3, 3) `cov` (body frame x, y, yaw) with the variance along the degenerate
    translation direction raised by `FREE_M2`; unchanged when there is none.

    The direction is known only to within the check's own angle: structure whose normals
    tilt less than that is one wall to it, and a wall seen at grazing incidence looks
    rotated in the sonar's frame by a bias that moves with the vehicle. The match's motion
    along the wall, s, then leaks s * tan(tilt) into the direction across it. That leak is
    a bias shared by every match along the wall (and through the odometry's scale state it
    adds up), so `translation_m` (2,), the match's translation, and `tilt`, tan of that
    angle, add its square as variance across the free direction. The two scans see
    different stretches of the structure only as far as it reaches: the slide is at most
    `found.extent_m`, the paired points' length along the wall (a lone piling's arc, seen
    from two sides of a loop, is one short structure, not a long tilted one)."""
    if not found.degenerate:
        return cov
    v = np.array([*found.direction, 0.0])
    out = cov + FREE_M2 * np.outer(v, v)
    if translation_m is not None and tilt > 0:
        u = np.array([-v[1], v[0], 0.0])
        slide = min(abs(float(np.dot(translation_m, v[:2]))), found.extent_m)
        out = out + (slide * tilt) ** 2 * np.outer(u, u)
    return out
