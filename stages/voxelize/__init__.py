"""Stage `voxelize` (world-frame maps and voxel counts); see `stages.voxelize.stage`."""

from stages.voxelize.stage import STAGE

__all__ = ["STAGE"]
