"""The trust report: what a run says about its own map without ground truth (issue 37.6)."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from sonarmap.pipeline.scoring import classification_scores
from sonarmap.schemas.map import MAP_SCHEMA
from sonarmap.schemas.slam import COVARIANCE_COLUMNS, FACTORS_SCHEMA, POSES_SCHEMA
from sonarmap.schemas.submaps import KEYFRAME_FRAME_ID
from sonarmap.stages.evaluate.trust import column_agreement, trust_markdown, trust_report


def _brute_force(q: np.ndarray, f: np.ndarray, cell: float, tol: float) -> tuple[list, list]:
    has, agrees = [], []
    cq, cf = np.floor(q[:, :2] / cell), np.floor(f[:, :2] / cell)
    for i in range(len(q)):
        same = (cf == cq[i]).all(axis=1)
        has.append(bool(same.any()))
        agrees.append(bool(same.any() and (np.abs(f[same, 2] - q[i, 2]) <= tol).any()))
    return has, agrees


def test_column_agreement_equals_the_brute_force_answer_on_random_clouds() -> None:
    rng = np.random.default_rng(7)
    agreeing = 0
    for cell, tol in ((1.0, 0.3), (0.5, 0.05), (2.0, 1.5)):
        # Negative coordinates, heights far outside the fused span, empty columns: all occur.
        q = rng.uniform(-6, 6, (400, 3)) * [1, 1, 2]
        f = rng.uniform(-4, 4, (150, 3))
        has, agrees = column_agreement(q, f, cell, tol)
        want_has, want_agrees = _brute_force(q, f, cell, tol)
        assert has.tolist() == want_has and agrees.tolist() == want_agrees
        assert agrees.sum() < has.sum() < len(q)
        agreeing += int(agrees.sum())
    assert agreeing > 0


def test_column_agreement_without_fused_points_checks_nothing() -> None:
    has, agrees = column_agreement(np.ones((3, 3)), np.zeros((0, 3)), 1.0, 0.5)
    assert not has.any() and not agrees.any()


def _map(rows: list[tuple[int, float, float, float, str, str]]) -> pa.Table:
    k, x, y, z, source, name = zip(*rows, strict=True)
    return pa.table(
        {
            "keyframe_id": np.array(k, np.int64),
            "frame_id": np.full(len(k), KEYFRAME_FRAME_ID, np.int64),
            "x_m": x,
            "y_m": y,
            "z_m": z,
            "source": source,
            "class_name": name,
        },
        schema=MAP_SCHEMA,
    )


def _poses(xy: np.ndarray) -> pa.Table:
    k = len(xy)
    cols: dict[str, object] = {"keyframe_id": np.arange(k), "t_ns": np.arange(k) * 10**9}
    cols.update(x_m=xy[:, 0], y_m=xy[:, 1], z_m=np.zeros(k), roll_rad=np.zeros(k))
    cols.update(pitch_rad=np.zeros(k), yaw_rad=np.zeros(k))
    cols.update({c: np.zeros(k) for c in COVARIANCE_COLUMNS})
    return pa.table(cols, schema=POSES_SCHEMA)


def _factors(rows: list[tuple[str, str, str, float | None]]) -> pa.Table:
    n = len(rows)
    kind, status, reason, rmse = zip(*rows, strict=True)
    cols: dict[str, object] = {
        "factor_id": np.arange(n),
        "type": kind,
        "key_from": np.zeros(n, np.int64),
        "key_to": np.ones(n, np.int64),
        "x_m": np.zeros(n),
        "y_m": np.zeros(n),
        "yaw_rad": np.zeros(n),
    }
    cols.update({c: np.zeros(n) for c in COVARIANCE_COLUMNS})
    cols.update(status=status, reason=reason, overlap_points=np.zeros(n, np.int64))
    cols["rmse_m"] = pa.array(rmse, pa.float64())
    cols["degenerate"] = [""] * n
    return pa.table(cols, schema=FACTORS_SCHEMA)


def test_the_report_counts_agreement_per_class_fused_keyframes_closures_and_drift() -> None:
    m = _map(
        [
            (0, 0.5, 0.5, -2.0, "fused", "seawall"),
            (2, 3.5, 0.5, -1.0, "fused", "cylindrical_piling"),
            (1, 0.4, 0.6, -2.3, "inferred", "seawall"),  # agrees (0.3 m)
            (1, 0.6, 0.4, -4.0, "inferred", "seawall"),  # checkable, disagrees
            (1, 9.5, 9.5, -2.0, "inferred", "seawall"),  # no fused point in its column
            (1, 3.6, 0.2, -1.5, "inferred", "cylindrical_piling"),  # agrees
        ]
    )
    slam = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 4.0]])
    dead_reckoning = slam + np.array([[0.0, 0.0], [0.0, 0.5], [0.0, 1.0]])
    factors = _factors(
        [
            ("loop", "accepted", "", 0.2),
            ("loop", "accepted", "", 0.4),
            ("loop", "rejected", "pcm: not in a consistent set", None),
            ("ssm", "rejected", "too few points", None),
            ("odometry", "accepted", "", None),
        ]
    )
    trust = trust_report(m, _poses(dead_reckoning), _poses(slam), factors, 1.0, 0.6)
    wall = trust["inference"]["per_class"]["seawall"]
    assert (wall["inferred_points"], wall["with_fused_evidence"], wall["agreeing"]) == (3, 2, 1)
    assert wall["checkable_share"] == round(2 / 3, 4) and wall["agreeing_share_of_checkable"] == 0.5
    assert trust["inference"]["per_class"]["cylindrical_piling"]["agreeing"] == 1
    assert trust["keyframes_with_fused_points"] == 2 and trust["keyframes"] == 3
    loop = trust["scan_matching"]["loop"]
    assert (loop["proposed"], loop["accepted"], loop["rejected"]) == (3, 2, 1)
    assert loop["rejected_by_reason"] == {"pcm: not in a consistent set": 1}
    assert loop["icp_rmse_m"]["median"] == 0.3 and loop["icp_rmse_m"]["max"] == 0.4
    assert trust["scan_matching"]["ssm"]["icp_rmse_m"]["median"] is None
    drift = trust["dead_reckoning_vs_slam"]
    assert drift["final_m"] == 1.0 and drift["max_m"] == 1.0 and drift["path_length_m"] == 7.0
    text = "\n".join(trust_markdown(trust))
    assert "| seawall | 3 | 66.7% | 50.0% |" in text
    assert "3 proposed, 2 accepted, 1 rejected (pcm: not in a consistent set: 1)" in text
    assert "ICP fit RMSE of the accepted: median 0.300 m, p90 0.380 m" in text
    assert "1.0 m apart at the end" in text
    assert trust["warnings"] == [] and "warning" not in text

    # With the slam stage's summary (sonarmap.stages.slam.health): its degenerate matches,
    # its drift check and its warning reach the report.
    summary = {
        "fell_back_to_dead_reckoning": False,
        "scan_matching": {
            "ssm": {"degenerate": 4, "degenerate_by_direction": {"x": 3, "y": 1}},
            "loop": {"degenerate": 0, "degenerate_by_direction": {}},
        },
        "dead_reckoning_vs_slam": {
            "gap_at_worst_m": 2.9,
            "predicted_bound_at_worst_m": 1.1,
            "worst_keyframe_id": 41,
            "exceeds_prediction": True,
        },
        "odometry_scale_error": {
            "forward": 0.0142,
            "sideways": -0.0011,
            "prior_sigma": 0.01,
            "beyond_prior": False,
        },
        "warnings": ["slam: SLAM and dead reckoning part by 2.90 m"],
    }
    trust = trust_report(m, _poses(dead_reckoning), _poses(slam), factors, 1.0, 0.6, summary)
    assert trust["warnings"] == summary["warnings"]
    assert trust["slam"]["degenerate_matches"]["ssm"] == {
        "found": 4,
        "by_direction": {"x": 3, "y": 1},
    }
    text = "\n".join(trust_markdown(trust))
    assert "sequential scan matches found degenerate" in text and "(x: 3, y: 1)" in text
    assert "loop closures found degenerate" not in text
    assert "2.9 m apart at keyframe 41, more than its 99 % bound there (1.1 m)" in text
    assert "- **warning:** slam: SLAM and dead reckoning part by 2.90 m" in text
    assert (
        "scale error as SLAM estimates it: +1.42 % forward, -0.11 % sideways (prior 1.0 %)" in text
    )


def test_an_unlabelled_recording_reports_no_precision_or_support_at_all() -> None:
    objects = pa.table({"class_name": ["seawall", "unknown"], "true_class_name": ["", ""]})
    assert classification_scores(objects) == {"objects": 2}
    labelled = pa.table({"class_name": ["seawall", "unknown"], "true_class_name": ["seawall", ""]})
    assert classification_scores(labelled)["per_class"]["seawall"]["support"] == 1


def test_evaluate_reports_trust_with_and_without_ground_truth() -> None:
    from test_evaluate import map_table, square_piling_faces, stage_inputs

    from sonarmap.stages.evaluate.stage import STAGE, EvaluateConfig

    centroid, _ = square_piling_faces()
    source = np.array(
        ["fused", "inferred"] * (len(centroid) // 2) + ["fused"] * (len(centroid) % 2)
    )
    for truth in (False, True):
        inputs = stage_inputs(map_table(centroid, source), truth)
        out = STAGE.run(EvaluateConfig(), {**inputs, "slam.factors": None})
        trust = out["metrics"]["trust"]
        assert trust["keyframes"] == 4 and trust["scan_matching"] is None
        assert trust["inference"]["per_class"]["cylindrical_piling"]["inferred_points"] == int(
            (source == "inferred").sum()
        )
        assert "## Trust (no ground truth needed)" in out["report"].decode()
