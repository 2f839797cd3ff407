"""Stage `voxelize` (world-frame maps and voxel counts); see `stages.voxelize.stage`."""

from stages.voxelize.registration import (
    pose_matrices,
    rotation_rpy,
    transform_grouped,
    voxel_keys,
    world_points,
)
from stages.voxelize.stage import (
    STAGE,
    VoxelizeConfig,
    build_map,
    height_colours,
    map_xyz,
    voxel_table,
)

__all__ = [
    "STAGE",
    "VoxelizeConfig",
    "build_map",
    "height_colours",
    "map_xyz",
    "pose_matrices",
    "rotation_rpy",
    "transform_grouped",
    "voxel_keys",
    "voxel_table",
    "world_points",
]
