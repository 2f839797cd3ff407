"""The `figures` stage: overlay.png and trajectory.png (the map's: `stages.map_figures`).

Modules:
    stage: the stage (why the figures are stages of their own).
    overlay: overlay.png, classified objects over one keyframe's horizontal image.
    trajectory: trajectory.png, the SLAM estimate beside dead reckoning and ground truth.
"""

from stages.figures.stage import STAGE, FiguresConfig

__all__ = ["STAGE", "FiguresConfig"]
