"""The `voxelize` stage (paper Sec. V, Eq. 4, Table I): world-frame maps and voxel counts.

This module declares the stage (what planning imports: no numpy, no pyarrow).

Modules:
    config: its config section.
    stage: the computation (`evidence`: the fused-evidence check of inferred points).
"""

from sonarmap.stages.base import Input, Output, Stage
from sonarmap.stages.kernels.lazy import deferred
from sonarmap.stages.voxelize.config import XYZ, VoxelizeConfig

__all__ = ["STAGE", "VoxelizeConfig"]

STAGE = Stage(
    name="voxelize",
    # 2: map.parquet gains frame_id; submap frames join the maps
    # 3: inferred beam-frame points that the fused points contradict are dropped
    version=4,  # 4: the PLYs gain vertex properties class_id, source, keyframe_id
    config=VoxelizeConfig,
    reads_sections=("classes",),
    inputs=(
        Input("infer", "points"),
        Input("fuse", "fused"),
        Input("slam", "poses"),
        Input("keyframes", "sensors"),
        Input("submaps", "frames"),
        Input("submaps", "points"),
    ),
    input_columns=(
        (Input("infer", "points"), ("keyframe_id", "source", "class_name", *XYZ)),
        (Input("fuse", "fused"), ("keyframe_id", *XYZ)),
        (Input("submaps", "points"), ("frame_id", "source", "class_name", *XYZ)),
    ),
    outputs=(
        Output("map", "parquet", "map.parquet", schema="sonarmap.schemas.map:MAP_SCHEMA"),
        Output("voxels", "parquet", "voxels.parquet", schema="sonarmap.schemas.map:VOXELS_SCHEMA"),
        Output("summary", "json", "summary.json"),
        Output("map_standard", "bytes", "map_standard.ply"),
        Output("map_semantic", "bytes", "map_semantic.ply"),
    ),
    run=deferred("sonarmap.stages.voxelize.stage:_run"),
    description="register points with SLAM poses (Eq. 4), standard and semantic maps, voxel counts",
)
