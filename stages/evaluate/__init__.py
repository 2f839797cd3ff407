"""The `evaluate` stage: map and trajectory quality against ground truth and the report.

Modules:
    stage: the stage.
    class_accounting: coverage and error per true class.
    submaps: the map with and without its dense submap frames, side by side.
    report: report.md (its figures: the `map_figures` stage, `stages.map_figures`).
    side_panels: the data of side_view.png (side_view.parquet).
"""

from stages.evaluate.stage import (
    STAGE,
    EvaluateConfig,
    map_errors,
    surface_metrics,
    trajectory_errors,
)

__all__ = ["STAGE", "EvaluateConfig", "map_errors", "surface_metrics", "trajectory_errors"]
