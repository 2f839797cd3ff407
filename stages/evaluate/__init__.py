"""The `evaluate` stage: map and trajectory quality against ground truth, figures and the report.

Modules:
    stage: the stage.
    class_accounting: coverage and error per true class.
    submaps: the map with and without its dense submap frames, side by side.
    report: report.md and its figures.
"""

from stages.evaluate.stage import (
    STAGE,
    EvaluateConfig,
    map_errors,
    surface_metrics,
    trajectory_errors,
)

__all__ = ["STAGE", "EvaluateConfig", "map_errors", "surface_metrics", "trajectory_errors"]
