"""The `evaluate` stage: map and trajectory quality against ground truth and the report.

This module declares the stage (what planning imports: no numpy, no pyarrow).

Modules:
    config: its config section and its figures' files.
    stage: the computation.
    class_accounting: coverage and error per true class.
    submaps: the map with and without its dense submap frames, side by side.
    report: report.md (its figures: the `map_figures` stage, `sonarmap.stages.map_figures`).
    side_panels: the data of side_view.png (side_view.parquet).
"""

from sonarmap.stages.base import Input, Output, Stage
from sonarmap.stages.evaluate.config import EvaluateConfig
from sonarmap.stages.kernels.lazy import deferred

__all__ = ["STAGE", "EvaluateConfig"]

STAGE = Stage(
    name="evaluate",
    # 6: metrics["submaps"] (issue 21), input submaps.stats; 7: per_class["assigned_classes"]
    # 8: map.mcap for Foxglove (issue 40), inputs frames and objects; 9: metrics["trust"]
    # 10: the figures move to the `map_figures` stage; side_view.parquet is the side view's
    # data, the report lists no figures; 11: the trust report carries slam's summary (matches
    # found degenerate, SLAM against the navigation's predicted drift, its warnings)
    # 12: the report's front-end section (inputs features.calibration, fuse.fused)
    # 13: the report's classifier section (input classify.acceptance)
    # 14: ... with the sure objects `classify.min_views` / `min_seen_share` held back
    # 15: report.md names no file (one key, one content whatever the recording is called)
    # 16: the trust section gives the odometry's scale error as SLAM estimates it
    # 17: the front-end section says a whole calibration pinned, in words (not a dict)
    version=17,
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
        Input("slam", "summary"),
        Input("infer", "stats"),
        Input("submaps", "stats"),
        Input("keyframes", "frames"),
        Input("classify", "objects"),
        Input("classify", "acceptance"),
        Input("features", "calibration"),
        Input("fuse", "fused"),
    ),
    outputs=(
        Output("metrics", "json", "metrics.json"),
        Output(
            "errors",
            "parquet",
            "errors.parquet",
            optional=True,
            schema="sonarmap.schemas.map:ERRORS_SCHEMA",
        ),
        Output("report", "bytes", "report.md"),
        Output(
            "side_view",
            "parquet",
            "side_view.parquet",
            optional=True,
            schema="sonarmap.schemas.figures:SIDE_VIEW_SCHEMA",
        ),
        Output("map_mcap", "bytes", "map.mcap"),
    ),
    run=deferred("sonarmap.stages.evaluate.stage:_run"),
    description="map error to the ground-truth mesh, completeness, ATE and the report",
)
