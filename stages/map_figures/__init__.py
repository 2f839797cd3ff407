"""The `map_figures` stage: errors.png, map_topdown.png, side_view.png of the evaluated map.

This module declares the stage (what planning imports: no numpy, no pyarrow, no matplotlib).

Modules:
    config: its config section.
    stage: the computation.
    plots: the figures, rendered to PNG bytes.
"""

from sonarmap.stages.base import Input, Output, Stage
from sonarmap.stages.kernels.lazy import deferred
from sonarmap.stages.map_figures.config import MapFiguresConfig

__all__ = ["STAGE", "MapFiguresConfig"]

STAGE = Stage(
    name="map_figures",
    # 2: top-down panels drawn as rasters of the highest point per cell (was a marker
    # per point)
    version=2,
    config=MapFiguresConfig,
    inputs=(
        Input("voxelize", "map"),
        Input("keyframes", "scene_mesh"),
        Input("slam", "poses"),
        Input("evaluate", "errors"),
        Input("evaluate", "side_view"),
    ),
    outputs=(
        Output("errors", "bytes", "errors.png", optional=True),
        Output("map_topdown", "bytes", "map_topdown.png"),
        Output("side_view", "bytes", "side_view.png", optional=True),
    ),
    run=deferred("sonarmap.stages.map_figures.stage:_run"),
    off_critical_path=True,
    input_columns=(
        (Input("voxelize", "map"), ("source", "x_m", "y_m", "z_m")),
        (Input("evaluate", "errors"), ("source", "error_m")),
    ),
    description="errors.png, map_topdown.png, side_view.png of the evaluated map",
)
