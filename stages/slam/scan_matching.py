"""2D scan matching of horizontal-sonar features (paper Sec. IV.A, SSM and NSSM).

Features are taken at elevation 0 (the paper assigns the unknown angle phi = 0), so each
keyframe is a planar point set in its base_link frame. A match has two steps:

1. Global initialisation by consensus-set maximisation: the target points are rasterised
   onto a grid and dilated by the point noise; every candidate pose on a coarse-to-fine
   lattice around the odometry guess scores the number of source points that land on
   occupied cells, and the best one seeds ICP (so ICP does not start in a wrong basin).
2. Point-to-point ICP with kiss-icp's `Registration` on the points padded with z = 0,
   projected back to SE(2); then the overlap (source points with a target neighbour within
   `overlap_radius_m`) and a covariance from the ICP Hessian.

All poses are (x_m, y_m, yaw_rad); "the pose of the source in the target frame" maps
source-frame points into the target frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sonarmap.stages.kernels.lazy import lazy
from sonarmap.stages.slam.pose_graph import wrap_angle
from sonarmap.stages.slam.targets import TargetIndex, pad_z

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

kiss_registration = lazy("kiss_icp.registration")
ndimage = lazy("scipy.ndimage")
spatial = lazy("scipy.spatial")

__all__ = [
    "MatchResult",
    "OccupancyScorer",
    "TargetIndex",
    "global_search",
    "icp_2d",
    "icp_covariance",
    "icp_with_covariance",
    "match_scans",
    "transform_points",
    "voxel_downsample",
]

_CHUNK_ELEMENTS = 2_000_000

_FOLD_LIMIT = 2**62
"""Voxel grids with fewer cells fold (x, y) indices into one int64 key."""


def transform_points(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map (N, 2) points by a (3,) pose (x_m, y_m, yaw_rad): ``R p + t``."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return points @ np.array([[c, s], [-s, c]]) + pose[:2]


def voxel_downsample(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """(N, 2) points -> (M, 2) centroids of occupied voxels, sorted by voxel (deterministic).

    Voxels are ordered by (x index, y index) and each centroid sums its points in input
    order, so the result is that of ``np.unique(keys, axis=0)`` with ``np.add.at``; the two
    indices are folded into one int64 because the row-wise unique sorts structured values
    about ten times slower (the slam stage downsamples ~1,600 clouds per mission).
    """
    if len(points) == 0:
        return np.zeros((0, 2))
    keys = np.floor(points / voxel_m).astype(np.int64)
    low = keys.min(axis=0)
    span = keys.max(axis=0) - low + 1
    if np.any(span <= 0) or float(span[0]) * float(span[1]) >= _FOLD_LIMIT:  # int64 overflow
        _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    else:
        folded = (keys[:, 0] - low[0]) * span[1] + (keys[:, 1] - low[1])
        _, inverse, counts = np.unique(folded, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    sums = np.stack(
        [np.bincount(inverse, points[:, i], minlength=len(counts)) for i in range(2)], axis=1
    )
    return sums / counts[:, None]


def _disk(resolution_m: float, radius_m: float) -> np.ndarray:
    """Structuring element of the cells within radius_m of the centre cell.

    The test is written as `distance_transform_edt` evaluates it (sqrt of the squared cell
    offsets, times the resolution), so dilating by it marks exactly the cells whose
    distance transform is within the radius, in a fraction of the time.
    """
    n = int(radius_m / resolution_m) + 1
    o = np.arange(-n, n + 1, dtype=np.float64)
    return np.sqrt(o[:, None] * o[:, None] + o[None, :] * o[None, :]) * resolution_m <= radius_m


class OccupancyScorer:
    """Dilated occupancy grid of a target point set; scores candidate source poses."""

    def __init__(self, target: np.ndarray, resolution_m: float, radius_m: float) -> None:
        """Args: target (M, 2) points [m]; grid resolution [m]; dilation radius [m]."""
        self.resolution_m = resolution_m
        margin = 2.0 * radius_m
        self.origin = target.min(axis=0) - margin
        shape = np.ceil((target.max(axis=0) + margin - self.origin) / resolution_m).astype(int) + 1
        cells = np.floor((target - self.origin) / resolution_m).astype(int)
        occupied = np.zeros(shape, dtype=bool)
        occupied[cells[:, 0], cells[:, 1]] = True
        self.grid = ndimage.binary_dilation(occupied, structure=_disk(resolution_m, radius_m))
        self.grid[[0, -1], :] = False
        self.grid[:, [0, -1]] = False
        self._flat = self.grid.ravel()

    def score(self, poses: np.ndarray, source: np.ndarray) -> np.ndarray:
        """(K,) number of source points (N, 2) that land on occupied cells, per (K, 3) pose.

        The grid's border cells are kept empty, so points outside are clipped onto them.
        """
        out = np.zeros(len(poses), dtype=np.int64)
        step = max(1, _CHUNK_ELEMENTS // max(1, len(source)))
        nx, ny = self.grid.shape
        inv = 1.0 / self.resolution_m
        for start in range(0, len(poses), step):
            p = poses[start : start + step]
            c, s = np.cos(p[:, 2])[:, None], np.sin(p[:, 2])[:, None]
            x = (c * source[:, 0] - s * source[:, 1] + (p[:, 0:1] - self.origin[0])) * inv
            y = (s * source[:, 0] + c * source[:, 1] + (p[:, 1:2] - self.origin[1])) * inv
            ix = np.clip(x, 0, nx - 1).astype(np.int64)
            iy = np.clip(y, 0, ny - 1).astype(np.int64)
            out[start : start + step] = self._flat[ix * ny + iy].sum(axis=1)
        return out

    def score_lattice(self, axes: list[np.ndarray], source: np.ndarray) -> np.ndarray:
        """`score` of every pose of the lattice `axes` (x, y, yaw values; `_lattice` order).

        A cell's x index depends only on a pose's (yaw, x) and its y index only on its
        (yaw, y), so each is computed once per pair, by the operations of `score` in its
        order: the same cells and counts, several times faster than per pose.
        """
        xs, ys, yaws = axes
        cx = self._cells(yaws, xs, source, 0).transpose(1, 0, 2) * self.grid.shape[1]
        cy = self._cells(yaws, ys, source, 1).transpose(1, 0, 2)
        out = np.empty((len(xs), len(ys), len(yaws)), dtype=np.int64)
        for i in range(len(xs)):  # one x at a time bounds the index array
            out[i] = self._flat[cx[i][None] + cy].sum(axis=-1)
        return out.ravel()

    def _cells(
        self, yaws: np.ndarray, shifts: np.ndarray, source: np.ndarray, axis: int
    ) -> np.ndarray:
        """(W, S, N) grid index along `axis` of the source rotated by each of W yaws and
        shifted by each of S shifts along that axis."""
        c, s = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
        if axis == 0:
            rotated = c * source[:, 0] - s * source[:, 1]
        else:
            rotated = s * source[:, 0] + c * source[:, 1]
        offset = (shifts - self.origin[axis])[None, :, None]
        moved = (rotated[:, None, :] + offset) * (1.0 / self.resolution_m)
        # int32 halves the memory traffic of the index arrays where the grid allows it.
        dtype = np.int32 if self.grid.size < 2**31 else np.int64
        return np.clip(moved, 0, self.grid.shape[axis] - 1).astype(dtype)


def _lattice_axes(center: np.ndarray, half: np.ndarray, steps: np.ndarray) -> list[np.ndarray]:
    return [c + np.arange(-h, h + 1e-9, s) for c, h, s in zip(center, half, steps, strict=True)]


def _lattice(axes: list[np.ndarray]) -> np.ndarray:
    """(K, 3) poses of the lattice over (x, y, yaw) `axes`: x slowest, yaw fastest."""
    grid = np.meshgrid(*axes, indexing="ij")
    return np.stack([g.ravel() for g in grid], axis=1)


def global_search(
    source: np.ndarray,
    scorer: OccupancyScorer,
    guess: np.ndarray,
    half_window: np.ndarray,
    levels: int = 3,
    points_per_axis: int = 9,
    tie_fraction: float = 1.0,
) -> tuple[np.ndarray, int]:
    """Consensus-set maximisation over a window around a guess, coarse to fine.

    Each level evaluates a `points_per_axis`^3 lattice over (x, y, yaw) centred on the best
    pose so far; the next level shrinks the window to two lattice steps. Among candidates
    scoring at least `tie_fraction` of the best, the one nearest the guess (in
    window-normalised units) wins: repeated structure (rows of pilings) gives near-equal
    peaks one spacing apart, and the odometry prior decides between them; this also keeps
    the result deterministic.

    Args:
        source: (N, 2) source points in the source frame.
        scorer: occupancy of the target, in the target frame.
        guess: (3,) pose of the source in the target frame (odometry).
        half_window: (3,) search half-widths (x_m, y_m, yaw_rad).
        levels: refinement levels.
        points_per_axis: lattice points per axis and level (odd).
        tie_fraction: fraction of the best consensus that counts as a tie.

    Returns:
        The best (3,) pose and its consensus (number of source points on occupied cells).
    """
    best, best_score = np.asarray(guess, np.float64), -1
    half = np.asarray(half_window, np.float64)
    for _ in range(levels):
        steps = 2.0 * half / (points_per_axis - 1)
        axes = _lattice_axes(best, half, steps)
        candidates = _lattice(axes)
        scores = scorer.score_lattice(axes, source)
        distance = np.linalg.norm((candidates - guess) / np.asarray(half_window), axis=1)
        near_best = scores >= tie_fraction * scores.max()
        pick = int(np.flatnonzero(near_best)[np.argmin(distance[near_best])])
        if scores[pick] > best_score:
            best, best_score = candidates[pick], int(scores[pick])
        half = 2.0 * steps
    best = best.copy()
    best[2] = float(wrap_angle(best[2]))
    return best, best_score


@dataclass(frozen=True)
class MatchResult:
    """One scan match.

    Attributes:
        pose: (3,) pose of the source in the target frame after ICP.
        initial: (3,) pose after the global search (ICP seed).
        consensus: points on occupied cells at `initial`.
        overlap: source points with a target neighbour within the overlap radius after ICP.
        rmse_m: RMS distance of those overlapping points to their neighbours [m].
        covariance: (3, 3) covariance of `pose` (source frame, order x, y, yaw).
    """

    pose: np.ndarray
    initial: np.ndarray
    consensus: int
    overlap: int
    rmse_m: float
    covariance: np.ndarray


def _to_matrix(pose: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose[2]), np.sin(pose[2])
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:2, 3] = pose[:2]
    return m


def icp_2d(
    source: np.ndarray,
    target: np.ndarray | TargetIndex,
    initial: np.ndarray,
    max_correspondence_m: float = 1.0,
    max_iterations: int = 40,
    voxel_m: float = 0.25,
) -> np.ndarray:
    """Point-to-point ICP with kiss-icp on (N, 2)/(M, 2) points padded with z = 0.

    Returns:
        (3,) pose of the source in the target frame (projection of kiss-icp's 4x4 to SE(2)).
    """
    index = target if isinstance(target, TargetIndex) else TargetIndex(target)
    voxel_map = index.voxel_map(voxel_m)
    registration = kiss_registration.Registration(max_iterations, 1e-4, max_num_threads=1)
    T = registration.align_points_to_map(
        points=pad_z(source),
        voxel_map=voxel_map,
        initial_guess=_to_matrix(initial),
        max_correspondance_distance=max_correspondence_m,
        kernel=max_correspondence_m / 3.0,
    )
    return np.array([T[0, 3], T[1, 3], np.arctan2(T[1, 0], T[0, 0])])


def icp_covariance(
    source: np.ndarray,
    target_tree: cKDTree,
    pose: np.ndarray,
    radius_m: float,
    effective_samples: float | None = None,
) -> tuple[int, float, np.ndarray]:
    """Overlap, RMSE and Hessian covariance of a point-to-point alignment.

    For inlier pairs (distance < radius_m) the residual Jacobian with respect to a body-frame
    perturbation is ``R [I | (-p_y, p_x)]``; the covariance is ``sigma^2 (J^T J)^{-1}`` with
    sigma^2 the mean squared inlier residual (at least (0.05 m)^2). Sonar residuals are
    not independent (a piling seen from another side shifts all of its points together);
    `effective_samples` (e.g. the number of objects) scales the covariance by
    n / effective_samples, None treats every inlier as independent.

    Returns:
        (overlap count, rmse_m, (3, 3) covariance; infinite diagonal if under 3 inliers).
    """
    moved = transform_points(pose, source)
    dist, _ = target_tree.query(moved, distance_upper_bound=radius_m)
    inlier = np.isfinite(dist)
    n = int(inlier.sum())
    if n < 3:
        return n, float("inf"), np.diag([np.inf, np.inf, np.inf])
    rmse = float(np.sqrt(np.mean(dist[inlier] ** 2)))
    p = source[inlier]
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, -s], [s, c]])
    local = np.zeros((n, 2, 3))
    local[:, 0, 0] = local[:, 1, 1] = 1.0
    local[:, 0, 2], local[:, 1, 2] = -p[:, 1], p[:, 0]
    jac = rot @ local
    hessian = np.einsum("nij,nik->jk", jac, jac)
    sigma2 = max(rmse**2, 0.05**2)
    scale = 1.0 if effective_samples is None else n / min(n, effective_samples)
    return n, rmse, sigma2 * scale * np.linalg.pinv(hessian)


def match_scans(
    source: np.ndarray,
    target: np.ndarray | TargetIndex,
    guess: np.ndarray,
    half_window: np.ndarray,
    grid_resolution_m: float = 0.1,
    radius_m: float = 0.5,
    max_correspondence_m: float = 1.0,
    max_iterations: int = 40,
    max_search_points: int = 400,
    tie_fraction: float = 1.0,
    effective_samples: float | None = None,
) -> MatchResult:
    """Global initialisation (consensus) then ICP, then overlap and covariance.

    Args:
        source: (N, 2) points in the source frame.
        target: (M, 2) points in the target frame.
        guess: (3,) odometry guess of the source pose in the target frame.
        half_window: (3,) search half-widths around the guess (x_m, y_m, yaw_rad).
        grid_resolution_m: occupancy grid cell size.
        radius_m: dilation radius of the grid and overlap radius (the point noise).
        max_correspondence_m: ICP correspondence gate.
        max_iterations: ICP iterations.
        max_search_points: the global search scores an even subsample of at most this many
            source points (ICP uses all).
        tie_fraction: see `global_search`.
        effective_samples: see `icp_covariance`.
    """
    index = target if isinstance(target, TargetIndex) else TargetIndex(target)
    scorer = OccupancyScorer(index.points, grid_resolution_m, radius_m)
    sample = source[:: max(1, -(-len(source) // max_search_points))]
    initial, consensus = global_search(
        sample, scorer, guess, half_window, tie_fraction=tie_fraction
    )
    pose, overlap, rmse, cov = icp_with_covariance(
        source, index, initial, max_correspondence_m, max_iterations, radius_m, effective_samples
    )
    return MatchResult(pose, initial, consensus, overlap, rmse, cov)


def icp_with_covariance(
    source: np.ndarray,
    target: np.ndarray | TargetIndex,
    initial: np.ndarray,
    max_correspondence_m: float,
    max_iterations: int,
    radius_m: float,
    effective_samples: float | None,
) -> tuple[np.ndarray, int, float, np.ndarray]:
    """ICP from `initial` (`icp_2d`, voxel radius_m / 2), then its overlap, RMSE and
    covariance (`icp_covariance`): (pose, overlap, rmse_m, (3, 3) covariance)."""
    index = target if isinstance(target, TargetIndex) else TargetIndex(target)
    pose = icp_2d(source, index, initial, max_correspondence_m, max_iterations, radius_m / 2)
    overlap, rmse, cov = icp_covariance(source, index.tree, pose, radius_m, effective_samples)
    return pose, overlap, rmse, cov
