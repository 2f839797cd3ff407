"""The `evaluate` stage: map and trajectory quality against ground truth, figures and the report.

This module declares the stage (what planning imports: no numpy, no pyarrow).

Modules:
    config: its config section and its figures' files.
    stage: the computation.
    class_accounting: coverage and error per true class.
    submaps: the map with and without its dense submap frames, side by side.
    report: report.md and its figures.
"""

from stages.base import Input, Output, Stage
from stages.evaluate.config import FIGURES, EvaluateConfig
from stages.kernels.lazy import deferred

__all__ = ["STAGE", "EvaluateConfig"]

STAGE = Stage(
    name="evaluate",
    # 6: metrics["submaps"] (issue 21), input submaps.stats; 7: per_class["assigned_classes"]
    # 8: map.mcap for Foxglove (issue 40), inputs frames and objects; 9: metrics["trust"]
    version=9,
    config=EvaluateConfig,
    reads_sections=("classes",),
    inputs=(
        Input("voxelize", "map"),
        Input("voxelize", "summary"),
        Input("keyframes", "keyframes"),
        Input("keyframes", "scene_mesh"),
        Input("keyframes", "sensors"),
        Input("slam", "poses"),
        Input("slam", "factors"),
        Input("infer", "stats"),
        Input("submaps", "stats"),
        Input("keyframes", "frames"),
        Input("classify", "objects"),
    ),
    outputs=(
        Output("metrics", "json", "metrics.json"),
        Output(
            "errors", "parquet", "errors.parquet", optional=True, schema="schemas.map:ERRORS_SCHEMA"
        ),
        Output("report", "bytes", "report.md"),
        *(Output(k, "bytes", f, optional=True) for k, f in FIGURES.items()),
        Output("map_mcap", "bytes", "map.mcap"),
    ),
    run=deferred("stages.evaluate.stage:_run"),
    description="map error to the ground-truth mesh, completeness, ATE, figures and report",
)
