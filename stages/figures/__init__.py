"""The `figures` stage: overlay.png and trajectory.png (the map's: `sonarmap.stages.map_figures`).

This module declares the stage (what planning imports: no numpy, no pyarrow, no matplotlib).

Modules:
    config: its config section.
    stage: the computation (why the figures are stages of their own).
    overlay: overlay.png, classified objects over one keyframe's horizontal image.
    trajectory: trajectory.png, the SLAM estimate beside dead reckoning and ground truth.
"""

from sonarmap.stages.base import Input, Output, Stage
from sonarmap.stages.figures.config import FiguresConfig
from sonarmap.stages.kernels.lazy import deferred

__all__ = ["STAGE", "FiguresConfig"]

STAGE = Stage(
    name="figures",
    # 2: overlay.png draws the fan as a Cartesian raster (was 77k pcolormesh quads)
    version=2,
    config=FiguresConfig,
    reads_sections=("classes", "slam"),
    draws=True,  # the class table's colours
    inputs=(
        Input("keyframes", "frames"),
        Input("keyframes", "keyframes"),
        Input("classify", "objects"),
        Input("slam", "poses"),
        Input("slam", "factors"),
        Input("slam", "plot_points"),
    ),
    outputs=(
        Output("overlay", "bytes", "overlay.png", optional=True),
        Output("trajectory", "bytes", "trajectory.png"),
    ),
    run=deferred("sonarmap.stages.figures.stage:_run"),
    off_critical_path=True,
    description="overlay.png (classified objects) and trajectory.png (SLAM), nothing waits",
)
