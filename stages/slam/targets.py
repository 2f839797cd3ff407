"""A scan-matching target cloud with its search structures, kept between matches."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from sonarmap.stages.kernels.lazy import lazy

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

kiss_mapping = lazy("kiss_icp.mapping")
spatial = lazy("scipy.spatial")

__all__ = ["TargetIndex", "pad_z"]


def pad_z(points: np.ndarray) -> np.ndarray:
    """(N, 2) planar points -> (N, 3) with z = 0 (kiss-icp works in 3D)."""
    return np.column_stack([points, np.zeros(len(points))])


class TargetIndex:
    """A target cloud's search structures, built on first use and kept for every match
    against it: kiss-icp's voxel map (per voxel size) and a k-d tree. Several matches
    register on one target cloud (the loop re-registration asks for the same stretch of
    track for every loop into it); reusing them changes no result."""

    def __init__(self, points: np.ndarray) -> None:
        self.points = points
        self._maps: dict[float, Any] = {}
        self._tree: cKDTree | None = None

    def voxel_map(self, voxel_m: float) -> Any:
        """kiss-icp `VoxelHashMap` of the points padded with z = 0 (never modified)."""
        if voxel_m not in self._maps:
            voxel_map = kiss_mapping.VoxelHashMap(
                voxel_size=voxel_m, max_distance=1e6, max_points_per_voxel=20
            )
            voxel_map.add_points(pad_z(self.points))
            self._maps[voxel_m] = voxel_map
        return self._maps[voxel_m]

    @property
    def tree(self) -> cKDTree:
        if self._tree is None:
            self._tree = spatial.cKDTree(self.points)
        return self._tree
