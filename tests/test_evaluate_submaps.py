"""evaluate with dense submaps (issue 21): keyframes-only vs with-submaps figures of both
maps against hand-computed truth, the report section, and no block without submap rows.

The truth is two 0.9 m x 0.1 m walls in the plane x = 5 m (y < 0: a rectangular piling,
y > 0: a round one), seen whole from keyframes at x = 0 looking along +x. Map points lie
on one row z = -1.99 m at voxel centres in y, `x - 5` m off the wall, so every error,
voxel and accurate voxel is known; one row of points every 0.1 m covers a wall's whole
visible surface within 0.1 m, and the other wall not at all.
"""

from __future__ import annotations

import functools
import json

import numpy as np
import pyarrow as pa
import pytest

from sonarmap.pipeline.experiments.sweep import RunOutcome, sweep_tables
from sonarmap.schemas.classes import CLASS_IDS
from sonarmap.schemas.map import MAP_SCHEMA, MAP_SORT_KEYS
from sonarmap.schemas.slam import COVARIANCE_COLUMNS, POSES_SCHEMA
from sonarmap.stages.evaluate.class_accounting import remember_last
from sonarmap.stages.evaluate.report import render_markdown
from sonarmap.stages.evaluate.stage import STAGE, EvaluateConfig

SECTION = "## Dense submaps: keyframes only vs with submap frames"
WALL_X_M = 5.0
KEYFRAMES_XY = np.array([[0.0, 0.0], [0.0, 0.5], [0.0, -0.5]])
Y_A = -0.95 + 0.1 * np.arange(9)  # voxel centres along the rectangular wall, y in [-1, -0.1]
Y_B = 0.15 + 0.1 * np.arange(9)  # along the round one, y in [0.1, 1]


def walls_ply() -> bytes:
    """ASCII PLY of the two walls (x = 5, z in [-2.05, -1.95]) with object and class ids."""
    verts, faces = [], []
    for obj, (y0, y1, cls) in enumerate(
        [(-1.0, -0.1, "rectangular_piling"), (0.1, 1.0, "cylindrical_piling")]
    ):
        base = len(verts)
        for y, z in ((y0, -2.05), (y1, -2.05), (y1, -1.95), (y0, -1.95)):
            verts.append(f"{WALL_X_M} {y} {z} {obj} {CLASS_IDS[cls]}")
        faces += [f"3 {base} {base + 1} {base + 2}", f"3 {base} {base + 2} {base + 3}"]
    header = [
        "ply",
        "format ascii 1.0",
        f"element vertex {len(verts)}",
        *(f"property float {c}" for c in "xyz"),
        "property int object_id",
        "property uchar class_id",
        f"element face {len(faces)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    return ("\n".join([*header, *verts, *faces]) + "\n").encode("ascii")


def rows(
    y: np.ndarray, off_m: float, z_m: float, source: str, frame: int, shift_m: float
) -> dict[str, list[object]]:
    n = len(y)
    return {
        "keyframe_id": [max(frame, 0)] * n,
        "frame_id": [frame] * n,
        "x_m": [WALL_X_M + off_m + shift_m] * n,
        "y_m": list(y),
        "z_m": [z_m] * n,
        "source": [source] * n,
        "class_name": ["none"] * n,
    }


def map_table(with_submaps: bool, shift_m: float = 0.0) -> pa.Table:
    """Keyframe rows (frame -1) and, optionally, two submap frames' rows (module doc)."""
    parts = [
        rows(Y_A, 0.02, -1.99, "fused", -1, shift_m),  # 9 voxels, error 0.02
        rows(Y_A[:3], 0.04, -2.04, "inferred", -1, shift_m),  # 3 voxels, error 0.04
    ]
    if with_submaps:
        parts += [
            rows(Y_B, 0.04, -1.99, "fused", 0, shift_m),  # 9 voxels, error 0.04
            rows(Y_B[:3], 0.35, -1.99, "fused", 1, shift_m),  # 3 voxels, inaccurate
            rows(Y_B[:2], 0.35, -2.04, "inferred", 1, shift_m),  # 2 voxels, inaccurate
        ]
    cols = {k: [v for p in parts for v in p[k]] for k in MAP_SCHEMA.names}
    table = pa.table(cols, schema=MAP_SCHEMA)
    return table.sort_by([(k, "ascending") for k in MAP_SORT_KEYS])


def pose_columns(xy: np.ndarray, prefix: str = "") -> dict[str, object]:
    k = len(xy)
    cols: dict[str, object] = {f"{prefix}x_m": xy[:, 0], f"{prefix}y_m": xy[:, 1]}
    cols.update({f"{prefix}z_m": np.full(k, -2.0)})
    cols.update({f"{prefix}{c}": np.zeros(k) for c in ("roll_rad", "pitch_rad", "yaw_rad")})
    return cols


def stage_inputs(m: pa.Table, slam_shift_m: float = 0.0) -> dict[str, object]:
    k = len(KEYFRAMES_XY)
    ids = {"keyframe_id": np.arange(k), "t_ns": np.arange(k) * 10**9}
    keyframes = pa.table(
        {**ids, **pose_columns(KEYFRAMES_XY), **pose_columns(KEYFRAMES_XY, "gt_")}
    ).append_column("reason", pa.array(["first"] + ["distance"] * (k - 1)))
    slam_xy = KEYFRAMES_XY + np.array([slam_shift_m, 0.0])
    covariance = {c: np.zeros(k) for c in COVARIANCE_COLUMNS}
    poses = pa.table({**ids, **pose_columns(slam_xy), **covariance}, schema=POSES_SCHEMA)
    return {
        "voxelize.map": m,
        "voxelize.summary": {"voxel_size_m": 0.1, "voxels": {}, "points": {}},
        "keyframes.keyframes": keyframes,
        "keyframes.scene_mesh": walls_ply(),
        "keyframes.sensors": {
            "horizontal": {"T_base_sonar": np.eye(4).tolist()},
            "source": {"name": "walls-test"},
        },
        "slam.poses": poses,
        "submaps.stats": {"stride": 4, "frames": 2},
    }


@functools.cache
def evaluate(with_submaps: bool, shift_m: float = 0.0) -> dict[str, object]:
    """The stage's outputs; shift_m moves the map and the SLAM poses along +x alike."""
    config = EvaluateConfig(surface_samples_per_m2=2000.0)  # 360 samples on the walls
    out = STAGE.run(config, stage_inputs(map_table(with_submaps, shift_m), shift_m))
    return dict(out)


def metrics(with_submaps: bool, shift_m: float = 0.0) -> dict[str, object]:
    m = evaluate(with_submaps, shift_m)["metrics"]
    assert isinstance(m, dict)
    return m


def test_figures_of_both_maps_with_and_without_submap_frames_are_the_hand_computed_ones() -> None:
    block = metrics(True)["submaps"]
    assert block["stride"] == 4 and block["frames"] == 2
    assert block["frame"] == "ground_truth_poses"
    full, ratio = block["with_submaps"], block["ratio"]
    expected = {  # (points, voxels, accurate voxels, median error)
        ("keyframes_only", "standard"): (9, 9, 9, 0.02),
        ("keyframes_only", "semantic"): (12, 12, 12, 0.02),
        ("with_submaps", "standard"): (21, 21, 18, 0.04),  # 9 x 0.02, 9 x 0.04, 3 x 0.35
        ("with_submaps", "semantic"): (26, 26, 21, 0.04),  # 9 x 0.02, 12 x 0.04, 5 x 0.35
    }
    for (variant, name), (points, voxels, accurate, median) in expected.items():
        fig = block[variant][name]
        assert (fig["points"], fig["voxels"], fig["accurate_voxels"]) == (points, voxels, accurate)
        assert fig["median_error_m"] == pytest.approx(median, abs=1e-5)
        assert fig["raw_median_error_m"] == fig["median_error_m"]  # no alignment to undo
    assert ratio["standard"]["accurate_voxels"] == pytest.approx(2.0)
    assert ratio["semantic"]["voxels"] == pytest.approx(26 / 12)
    assert ratio["standard"]["median_error_m"] == pytest.approx(2.0, rel=1e-3)
    assert (
        full["standard"]["voxels"]
        == metrics(True)["per_class"]["classes"]["all_structure"]["standard"]["voxels"]
    )
    json.dumps(block, allow_nan=False)  # what the engine writes


def test_completeness_counts_the_same_visible_samples_and_the_wall_the_submaps_add() -> None:
    block = metrics(True)["submaps"]
    kf, full = block["keyframes_only"]["per_class"], block["with_submaps"]["per_class"]
    # The keyframes cover the rectangular wall only; the submap frames add the round one.
    for name in ("standard", "semantic"):
        assert kf["rectangular_piling"][name]["completeness"] == 1.0
        assert kf["cylindrical_piling"][name]["completeness"] == 0.0
        assert full["cylindrical_piling"][name]["completeness"] == 1.0
    seen = {c: full[c]["visible_samples"] for c in ("rectangular_piling", "cylindrical_piling")}
    assert sum(seen.values()) == 360  # 0.18 m2 at 2000 / m2: the walls are seen whole
    assert {c: kf[c]["visible_samples"] for c in seen} == seen
    share = seen["rectangular_piling"] / sum(seen.values())
    assert block["keyframes_only"]["standard"]["completeness"] == pytest.approx(share)
    assert block["with_submaps"]["standard"]["completeness"] == 1.0
    assert block["ratio"]["standard"]["completeness"] == pytest.approx(1.0 / share)


def test_keyframes_only_figures_equal_a_run_on_the_keyframe_rows_alone() -> None:
    alone, block = metrics(False), metrics(True)["submaps"]["keyframes_only"]
    whole = alone["per_class"]["classes"]["all_structure"]
    for name in ("standard", "semantic"):
        assert block[name]["accurate_voxels"] == whole[name]["accurate_voxels"]
        assert block[name]["completeness"] == whole[name]["completeness"]
        assert block[name]["median_error_m"] == alone["headline"]["median_m"][name]
    assert block["per_class"] == alone["per_class"]["classes"]


def test_after_the_se2_alignment_the_lead_median_is_aligned_and_the_raw_one_kept() -> None:
    m = metrics(True, shift_m=0.2)  # map and SLAM 0.2 m too far along +x
    block = m["submaps"]
    assert block["frame"] == "aligned" and block["label"] == m["headline"]["label"]
    for variant, standard in (("keyframes_only", 0.02), ("with_submaps", 0.04)):
        fig = block[variant]["standard"]
        assert fig["median_error_m"] == pytest.approx(standard, abs=1e-4)
        assert fig["raw_median_error_m"] == pytest.approx(standard + 0.2, abs=1e-4)
    assert block["with_submaps"]["standard"]["accurate_voxels"] == 18
    assert block["with_submaps"]["standard"]["median_error_m"] == pytest.approx(
        m["headline"]["median_m"]["standard"]
    )


def test_without_submap_rows_there_is_no_block_and_no_report_section() -> None:
    out = evaluate(False)
    assert "submaps" not in out["metrics"]
    assert SECTION not in out["report"].decode()


def test_the_report_has_the_submaps_table_and_its_class_rows() -> None:
    report = evaluate(True)["report"].decode()
    assert SECTION in report and "Submap stride 4: 2 submap frames" in report
    section = report[report.index(SECTION) :]
    assert "| standard | with submaps | 21 | 21 | 18 | 1.000 | 0.040 |" in section
    assert "| standard | **ratio** | 2.33x | 2.33x | 2.00x |" in section
    assert "| cylindrical_piling | standard | 0 / 12 | 0 / 9 | - | 0.000 / 1.000 |" in section
    again = render_markdown(evaluate(True)["metrics"], 3)
    assert SECTION in again.decode()


def test_without_a_mesh_only_points_and_voxels_are_compared() -> None:
    inputs = stage_inputs(map_table(True))
    inputs["keyframes.scene_mesh"] = None
    out = STAGE.run(EvaluateConfig(), inputs)
    block = out["metrics"]["submaps"]
    assert block["keyframes_only"]["standard"] == {
        "points": 9,
        "voxels": 9,
        "accurate_voxels": None,
        "completeness": None,
        "median_error_m": None,
        "raw_median_error_m": None,
    }
    assert block["with_submaps"]["semantic"]["voxels"] == 26 and block["frame"] is None
    assert "per_class" not in block["with_submaps"]
    assert "| semantic | **ratio** | 2.17x | 2.17x | - | - | - |" in out["report"].decode()


def test_sweep_rows_carry_the_submap_ratios_and_the_table_only_when_reported() -> None:
    with_block = {"metrics": metrics(True)}
    without = {"metrics": metrics(False)}
    outcomes = [
        RunOutcome("/d/a.mcap", {"keyframes.submap_stride": "4"}, "ok", 1.0, with_block),
        RunOutcome("/d/a.mcap", {"keyframes.submap_stride": "0"}, "ok", 1.0, without),
    ]
    table, _, markdown = sweep_tables(outcomes)
    rows = table.to_pylist()
    assert rows[0]["submap_frames"] == 2 and rows[1]["submap_frames"] is None
    assert rows[0]["submap_accurate_ratio_standard"] == pytest.approx(2.0)
    assert rows[0]["submap_median_error_ratio_semantic"] == pytest.approx(2.0, rel=1e-3)
    assert "submap_accurate_ratio_standard" in markdown
    _, _, plain = sweep_tables(outcomes[1:])
    assert "submap_frames" not in plain and "_ratio_standard" not in plain


def test_the_visibility_of_equal_samples_is_cast_once_and_of_new_samples_again() -> None:
    calls: list[int] = []

    def visible(samples: np.ndarray) -> np.ndarray:
        calls.append(len(samples))
        return samples[:, 0] > 0

    seen = remember_last(visible)
    a, b = np.array([[1.0, 0, 0], [-1.0, 0, 0]]), np.array([[-1.0, 0, 0]])
    assert seen(a).tolist() == [True, False] and seen(a.copy()).tolist() == [True, False]
    assert seen(b).tolist() == [False] and calls == [2, 1]
