"""The `map_figures` stage: errors.png, map_topdown.png, side_view.png of the evaluated map.

Modules:
    stage: the stage.
    plots: the figures, rendered to PNG bytes.
"""

from stages.map_figures.stage import STAGE, MapFiguresConfig

__all__ = ["STAGE", "MapFiguresConfig"]
