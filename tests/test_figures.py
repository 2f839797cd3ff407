"""The `figures` stage on small tables: what it reads from slam's and classify's artifacts.

(`map_figures`: tests/test_evaluate.py; both stages on a real run, and the map stages
without matplotlib: tests/test_cli_paths.py.)
"""

from __future__ import annotations

import io

import numpy as np
import pyarrow as pa
from PIL import Image
from test_evaluate import keyframes_table, poses_table

from sonarmap.schemas.figures import PLOT_POINTS_SCHEMA
from sonarmap.schemas.objects import OBJECTS_SCHEMA
from sonarmap.schemas.slam import COVARIANCE_COLUMNS, FACTORS_SCHEMA
from sonarmap.stages.figures import STAGE, FiguresConfig
from sonarmap.stages.figures.stage import _loops
from sonarmap.stages.slam.config import SlamConfig

PNG = b"\x89PNG\r\n\x1a\n"


def _factors(rows: list[tuple[str, int, int, str]]) -> pa.Table:
    """factors.parquet rows (type, key_from, key_to, status), the rest zero."""
    n = len(rows)
    cols: dict[str, object] = {
        "factor_id": np.arange(n),
        "type": [r[0] for r in rows],
        "key_from": [r[1] for r in rows],
        "key_to": [r[2] for r in rows],
        **{c: np.zeros(n) for c in ("x_m", "y_m", "yaw_rad", *COVARIANCE_COLUMNS)},
        "status": [r[3] for r in rows],
        "reason": [""] * n,
        "overlap_points": np.zeros(n, np.int64),
        "rmse_m": np.zeros(n),
        "degenerate": [""] * n,
    }
    return pa.table(cols, schema=FACTORS_SCHEMA)


def test_loops_are_the_keyframe_rows_of_the_accepted_loop_closures() -> None:
    ids = np.array([10, 20, 30, 40])
    factors = _factors(
        [
            ("odometry", 10, 20, "accepted"),
            ("loop", 40, 10, "accepted"),
            ("loop", 30, 20, "rejected"),
            ("loop", 30, 10, "accepted"),
        ]
    )
    assert _loops(factors, ids).tolist() == [[3, 0], [2, 0]]
    assert _loops(_factors([]), ids).shape == (0, 2)


def _inputs(with_truth: bool) -> dict[str, object]:
    t = np.linspace(0.0, 2 * np.pi, 30)
    xy, yaw = np.column_stack([10 * np.cos(t), 10 * np.sin(t)]), t + np.pi / 2
    cloud = np.column_stack([12 * np.cos(t), 12 * np.sin(t)])
    return {
        "keyframes.frames": [],
        "keyframes.keyframes": keyframes_table(xy + 0.3, xy if with_truth else None, yaw),
        "classify.objects": OBJECTS_SCHEMA.empty_table(),
        "slam.poses": poses_table(xy, yaw),
        "slam.factors": _factors([("loop", 29, 0, "accepted")]),
        "slam.plot_points": pa.table(
            {"x_m": cloud[:, 0], "y_m": cloud[:, 1]}, schema=PLOT_POINTS_SCHEMA
        ),
        "config.slam": SlamConfig(),
    }


def test_trajectory_png_from_slam_s_artifacts_and_no_overlay_without_objects() -> None:
    sizes = {}
    for with_truth in (True, False):
        out = STAGE.run(FiguresConfig(), _inputs(with_truth))
        assert out["overlay"] is None  # no object to draw
        assert out["trajectory"][:8] == PNG
        assert STAGE.run(FiguresConfig(), _inputs(with_truth))["trajectory"] == out["trajectory"]
        sizes[with_truth] = Image.open(io.BytesIO(out["trajectory"])).size
    assert sizes[False][0] == sizes[False][1]  # the map alone
    assert sizes[True][1] > 1.2 * sizes[True][0]  # over the error panel
    assert STAGE.run(FiguresConfig(overlay=False), _inputs(True))["overlay"] is None
