"""The headline map error leads with the aligned figure, names its alignment, keeps raw beside."""

from __future__ import annotations

import numpy as np
import pytest
from test_evaluate import (
    YAWS,
    keyframes_table,
    map_table,
    poses_table,
    square_piling_faces,
    stage_inputs,
)

from sonarmap.pipeline.experiments.headline_columns import headline_header, shared_frame
from sonarmap.pipeline.experiments.sweep import RunOutcome, sweep_tables
from sonarmap.stages.evaluate.headline import headline_errors
from sonarmap.stages.evaluate.stage import STAGE, EvaluateConfig
from sonarmap.stages.kernels.geometry import matrix_from_rpy

TRUTH_XY = np.array([[-6.0, -4.0], [5.0, -3.0], [6.0, 5.0], [-4.0, 6.0]])


def _rotated_run() -> dict:
    """A map and its SLAM trajectory turned 2° and shifted from the truth."""
    centroid, _ = square_piling_faces()
    R, t = matrix_from_rpy([0.0, 0.0, np.deg2rad(2.0)])[:2, :2], np.array([0.3, -0.2])
    moved = centroid.copy()
    moved[:, :2] = centroid[:, :2] @ R.T + t
    inputs = stage_inputs(map_table(moved, np.array(["fused"] * len(moved))), True)
    inputs["keyframes.keyframes"] = keyframes_table(TRUTH_XY, TRUTH_XY, YAWS)
    inputs["slam.poses"] = poses_table(TRUTH_XY @ R.T + t, YAWS)
    return dict(STAGE.run(EvaluateConfig(), inputs))


def test_report_leads_with_the_aligned_median_and_names_the_rotation() -> None:
    out = _rotated_run()
    head = out["metrics"]["headline"]
    assert head["frame"] == "aligned" and head["rotation_deg"] == pytest.approx(-2.0, abs=1e-6)
    assert head["median_m"]["standard"] == pytest.approx(0.0, abs=1e-4)
    assert head["raw_median_m"]["standard"] > 0.1
    first_table = out["report"].decode().split("## Coverage (paper Table I)")[1]
    header, _, row = first_table.strip().splitlines()[:3]
    cols = [c.strip() for c in header.strip("|").split("|")]
    assert cols[3] == "median error m, SE(2)-aligned (rotation -2.00°)"
    assert cols[4] == "raw median error m"
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[0] == "standard" and cells[3] == "**0.000**" and float(cells[4]) > 0.1


def test_poses_equal_to_the_truth_are_labelled_ground_truth_poses_without_a_raw_column() -> None:
    centroid, _ = square_piling_faces()
    out = STAGE.run(
        EvaluateConfig(),
        stage_inputs(map_table(centroid, np.array(["fused"] * len(centroid))), True),
    )
    head = out["metrics"]["headline"]
    assert head["frame"] == "ground_truth_poses" and head["rotation_deg"] is None
    assert head["median_m"] == head["raw_median_m"]
    report = out["report"].decode()
    assert "| median error m, ground-truth poses (no alignment) |" in report
    assert "raw median error m" not in report


def test_without_ground_truth_poses_the_raw_figure_says_so() -> None:
    errors = {"standard": {"median_m": 0.4}, "semantic": {"median_m": 0.5}}
    head = headline_errors(errors, None, on_ground_truth=False)
    assert head["frame"] == "raw" and head["median_m"] == {"standard": 0.4, "semantic": 0.5}
    assert "no ground-truth poses" in head["label"]


def test_sweep_table_puts_the_headline_before_the_raw_median_and_names_its_frame() -> None:
    metrics = _rotated_run()["metrics"]
    summary = {"voxels": {"standard": 10, "semantic": 30}, "metrics": metrics}
    runs = [RunOutcome("d.mcap", {"keyframes.spacing_m": s}, "ok", 1.0, summary) for s in "24"]
    table, groups, markdown = sweep_tables(runs)
    assert table.column("headline_frame").to_pylist() == ["aligned", "aligned"]
    assert groups[0]["headline_frame"] == "aligned"
    header = markdown.splitlines()[0]
    lead = "median_error_standard_m (SE(2)-aligned)"
    assert lead in header and header.index(lead) < header.index("| median_error_standard_m |")
    assert "alignment_rotation_deg" in header
    assert shared_frame(["aligned", "ground_truth_poses"]) == "mixed"
    assert headline_header("voxels_standard", "aligned") == "voxels_standard"


def test_study_table_i_leads_with_the_aligned_median_and_its_mean_rotation() -> None:
    from sonarmap.pipeline.experiments.study import table_i

    metrics = _rotated_run()["metrics"]
    summary = {"voxels": {"standard": 10, "semantic": 30}, "metrics": metrics}
    runs = [
        RunOutcome("d.mcap", {"keyframes.spacing_m": "4"}, "ok", 1.0, summary, protocol="default")
    ]
    header, _, row = table_i(sweep_tables(runs)[1]).splitlines()[:3]
    assert (
        "| median error m (ours, SE(2)-aligned; mean rotation) | raw median error m (ours) |"
        in (header)
    )
    assert "| 0.000 (-2.00°) |" in row
