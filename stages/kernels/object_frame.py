"""Per-class reference coordinate frame and ICP registration (paper Sec. IV.D).

An object sighting is a set of horizontal-sonar returns (slant range R, bearing theta).
Its *object frame* has its origin at the sighting's minimum range and median bearing
(R0, theta0) and is metric and aligned with the line of sight to that origin:

    u = R cos(theta - theta0) - R0        (range offset, away from the sonar)
    v = R sin(theta - theta0)             (cross-range, positive left like theta)

i.e. the sonar-frame 2D point rotated by -theta0 and shifted by -R0. The same
function converts both the 2D features and the fused 3D points of a sighting, with
the same origin (that of the whole 2D object), so the two never disagree (the
original code used a mirrored bearing axis for one of them and a different origin
for the 3D subset). The slant range is used for both, because a 2D-only return knows
only its slant range.

The first sighting of a class fixes the class's *reference frame*: its object frame,
and its points (voxel-downsampled) become the reference cloud. That reference is
*provisional* until another sighting registers to it: a provisional reference that the
next update cannot register is replaced by that sighting (`ClassFrame.confirmed`). The
paper keeps the first sighting for good, so one odd first sighting (a piling merged in
2D with the catwalk it carries) left every later one unregistered and the class
unlearned. Later sightings are
registered to the reference cloud with point-to-point ICP (open3d, 2D points padded
with z = 0, identity initial guess, metric units); a registration that does not
reach the fitness / RMSE / motion bounds is reported as failed and the caller skips
that sighting. Updates add their registered points to the reference cloud, which is
re-downsampled so it stays bounded; queries leave it unchanged.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from sonarmap.stages.kernels.geometry import fan_to_xy, se2, se2_apply
from sonarmap.stages.kernels.lazy import lazy

o3d = lazy("open3d")

__all__ = [
    "ClassFrame",
    "IcpParams",
    "ObjectOrigin",
    "Registration",
    "object_origin",
    "to_object_frame",
    "voxel_downsample_2d",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ObjectOrigin:
    """Origin of an object frame: minimum slant range [m] and median bearing [rad]."""

    range_m: float
    bearing_rad: float


def object_origin(range_m: np.ndarray, bearing_rad: np.ndarray) -> ObjectOrigin:
    """Origin of a sighting from all its (n,) 2D returns (n >= 1)."""
    if np.size(range_m) == 0:
        raise ValueError("an object sighting needs at least one return")
    return ObjectOrigin(float(np.min(range_m)), float(np.median(bearing_rad)))


def to_object_frame(
    range_m: np.ndarray, bearing_rad: np.ndarray, origin: ObjectOrigin
) -> np.ndarray:
    """(n, 2) object-frame coordinates (u, v) [m] of returns at (range, bearing):
    Eq. 1 at phi = 0 in the frame turned by the origin's bearing theta0 and shifted by its
    range R0, u = R cos(theta - theta0) - R0, v = R sin(theta - theta0)."""
    d = np.asarray(bearing_rad, dtype=np.float64) - origin.bearing_rad
    return fan_to_xy(range_m, d).reshape(-1, 2) - np.array([origin.range_m, 0.0])


def voxel_downsample_2d(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """Centroid of the (n, 2) points in each occupied square voxel, sorted by voxel."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if pts.shape[0] == 0:
        return pts
    ij = np.floor(pts / voxel_m).astype(np.int64)
    ij -= ij.min(axis=0)
    _, inverse = np.unique(ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1], return_inverse=True)
    inverse = inverse.reshape(-1)
    counts = np.bincount(inverse)
    return np.stack([np.bincount(inverse, pts[:, k]) / counts for k in range(2)], axis=1)


@dataclass(frozen=True)
class IcpParams:
    """Bounds of an object registration (metric, reference frame)."""

    max_correspondence_m: float = 0.5
    max_iterations: int = 30
    min_fitness: float = 0.6
    max_rmse_m: float = 0.15
    max_translation_m: float = 1.5
    max_rotation_rad: float = np.deg2rad(30.0)
    voxel_m: float = 0.05
    relative_tolerance: float = 1e-4
    min_points: int = 3


@dataclass(frozen=True)
class Registration:
    """Result of registering a sighting to a class reference frame.

    Attributes:
        T_ref_obj: (3, 3) transform of object-frame points into the reference frame.
        fitness: fraction of sighting points with a reference point within the
            correspondence distance.
        rmse_m: RMS distance of those inlier correspondences [m].
        ok: whether the bounds of `IcpParams` were met.
        reseeded: the sighting replaced a provisional reference (`ClassFrame.add_sighting`).
    """

    T_ref_obj: np.ndarray
    fitness: float
    rmse_m: float
    ok: bool
    reseeded: bool = False


def _cloud(points_2d: np.ndarray) -> o3d.geometry.PointCloud:
    xyz = np.zeros((points_2d.shape[0], 3))
    xyz[:, :2] = points_2d
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))


def register_2d(source: np.ndarray, target: np.ndarray, params: IcpParams) -> Registration:
    """Point-to-point ICP of (n, 2) source onto (m, 2) target, projected to SE(2).

    Fewer than `min_points` points on either side is a failed registration.
    """
    if min(len(source), len(target)) < params.min_points:
        return Registration(np.eye(3), 0.0, np.inf, False)
    reg = o3d.pipelines.registration
    result = reg.registration_icp(
        _cloud(source),
        _cloud(target),
        params.max_correspondence_m,
        np.eye(4),
        reg.TransformationEstimationPointToPoint(),
        reg.ICPConvergenceCriteria(
            relative_fitness=params.relative_tolerance,
            relative_rmse=params.relative_tolerance,
            max_iteration=params.max_iterations,
        ),
    )
    T4 = np.asarray(result.transformation)
    yaw = float(np.arctan2(T4[1, 0], T4[0, 0]))
    T = se2(T4[0, 3], T4[1, 3], yaw)
    ok = (
        result.fitness >= params.min_fitness
        and result.inlier_rmse <= params.max_rmse_m
        and float(np.hypot(T[0, 2], T[1, 2])) <= params.max_translation_m
        and abs(yaw) <= params.max_rotation_rad
        and abs(T4[2, 2] - 1.0) < 1e-6
    )
    return Registration(T, float(result.fitness), float(result.inlier_rmse), bool(ok))


class ClassFrame:
    """Reference frame and bounded reference cloud of one object class.

    Args:
        params: ICP and downsampling bounds.
    """

    def __init__(self, params: IcpParams) -> None:
        self.params = params
        self.reference: np.ndarray | None = None
        self.origin: ObjectOrigin | None = None
        self.confirmed = False

    def register(self, points_obj: np.ndarray) -> Registration:
        """Register (n, 2) object-frame points to the reference cloud (unchanged).

        Before the first sighting there is no reference: the result is not ok.
        """
        if self.reference is None:
            return Registration(np.eye(3), 0.0, np.inf, False)
        source = voxel_downsample_2d(points_obj, self.params.voxel_m)
        return register_2d(source, self.reference, self.params)

    def add_sighting(self, points_obj: np.ndarray, origin: ObjectOrigin) -> Registration:
        """Register a sighting for an update and grow the reference cloud with it.

        The first sighting defines the reference frame (identity registration); the first
        that registers to it confirms it. A failed registration leaves a confirmed
        reference unchanged; a provisional one is replaced by the sighting, which is then
        reported as registered with `reseeded` set (the caller drops what the old frame
        learned).
        """
        if self.reference is None:
            self._seed(points_obj, origin)
            return Registration(np.eye(3), 1.0, 0.0, True)
        result = self.register(points_obj)
        if result.ok:
            self.confirmed = True
            merged = np.vstack([self.reference, se2_apply(result.T_ref_obj, points_obj)])
            self.reference = voxel_downsample_2d(merged, self.params.voxel_m)
        elif not self.confirmed:
            logger.debug("provisional reference replaced: fitness %.2f", result.fitness)
            self._seed(points_obj, origin)
            return Registration(np.eye(3), 1.0, 0.0, True, reseeded=True)
        else:
            logger.debug("object registration failed: fitness %.2f", result.fitness)
        return result

    def _seed(self, points_obj: np.ndarray, origin: ObjectOrigin) -> None:
        self.reference = voxel_downsample_2d(points_obj, self.params.voxel_m)
        self.origin = origin
        self.confirmed = False
