"""`sonarmap study`: Table I beside the paper's, the cross ratio, per-class accounting, Fig. 4."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.experiments.study import write_study
from sonarmap.pipeline.experiments.study_fig4 import box_stats, pooled_errors
from sonarmap.pipeline.experiments.study_tables import (
    PAPER_CROSS_RATIO,
    assigned_class_rows,
    class_rows,
    cross_ratio_rows,
    table_i_rows,
)
from sonarmap.pipeline.experiments.sweep import RunOutcome, _flat, sweep_tables

PNG = b"\x89PNG\r\n\x1a\n"


def _class(
    std_vox: int, sem_vox: int, std_acc: int, sem_acc: int, c_std: float, c_sem: float, vis: int
) -> dict[str, Any]:
    return {
        "standard": {
            "points": 10 * std_vox,
            "voxels": std_vox,
            "accurate_voxels": std_acc,
            "completeness": c_std,
            "median_error_m": 0.05,
        },
        "semantic": {
            "points": 10 * sem_vox,
            "voxels": sem_vox,
            "accurate_voxels": sem_acc,
            "completeness": c_sem,
            "median_error_m": 0.07,
        },
        "inferred": {"points": 10 * (sem_vox - std_vox), "median_error_m": 0.09},
        "visible_samples": vis,
    }


def _summary(standard: int, semantic: int, scale: int = 1, per_class: bool = True) -> dict:
    metrics: dict[str, Any] = {
        "errors": {
            "standard": {"median_m": 0.04},
            "semantic": {"median_m": 0.06},
            "fused": {"median_m": 0.04},
            "inferred": {"median_m": 0.10},
        },
        "completeness": {"standard": 0.1, "semantic": 0.3},
    }
    if per_class:
        metrics["per_class"] = {
            "tolerance_m": 0.1,
            "voxel_size_m": 0.1,
            "frame": "raw",
            "classes": {
                "cylindrical_piling": _class(10 * scale, 200 * scale, 8, 150, 0.1, 0.5, 100),
                "rectangular_piling": _class(20 * scale, 100 * scale, 16, 60, 0.2, 0.8, 300),
                "seafloor": _class(500, 500, 400, 400, 0.3, 0.3, 1000),
                "all_structure": _class(30 * scale, 300 * scale, 24, 210, 0.175, 0.725, 400),
            },
            "assigned_classes": {
                "cylindrical_piling": {
                    "fused_median_error_m": 0.05,
                    "inferred_median_error_m": 0.05 * scale,
                    "inferred_over_fused": float(scale),
                },
                "rectangular_piling": {
                    "fused_median_error_m": 0.04,
                    "inferred_median_error_m": 0.06,
                    "inferred_over_fused": 1.5,
                },
                "unknown": {
                    "fused_median_error_m": 0.08,
                    "inferred_median_error_m": None,
                    "inferred_over_fused": None,
                },
            },
        }
    return {"voxels": {"standard": standard, "semantic": semantic}, "metrics": metrics}


def _outcomes(stages: dict[tuple[str, str, int], list[dict]] | None = None) -> list[RunOutcome]:
    """Two protocols x spacings 4, 2 x two trials, with known voxel counts."""
    counts = {
        ("default", "4"): [(100, 2000), (300, 4000)],  # mean 200 / 3000
        ("default", "2"): [(400, 5000), (600, 7000)],  # mean 500 / 6000
        ("paper", "4"): [(1000, 20000), (1000, 20000)],
        ("paper", "2"): [(2000, 30000), (4000, 50000)],  # mean 3000 / 40000
    }
    out = []
    for (protocol, spacing), runs in counts.items():
        for trial, (std, sem) in enumerate(runs):
            out.append(
                RunOutcome(
                    dataset=f"/d/trial{trial}.mcap",
                    overrides={"keyframes.spacing_m": spacing},
                    status="ok",
                    seconds=1.5 + trial,
                    summary=_summary(std, sem, scale=trial + 1),
                    stages=(stages or {}).get((protocol, spacing, trial), []),
                    protocol=protocol,
                    config_path=None if protocol == "default" else "configs/paper.yaml",
                )
            )
    return out


def test_flat_columns_carry_the_per_class_figures() -> None:
    row = _flat(_summary(10, 100))
    assert row["accurate_voxels_standard"] == 24 and row["accurate_voxels_semantic"] == 210
    assert row["accurate_ratio"] == pytest.approx(210 / 24)
    assert row["accurate_voxels_piling_standard"] == 8 + 16
    assert row["accurate_voxels_piling_semantic"] == 150 + 60
    assert row["completeness_all_standard"] == 0.175
    assert row["completeness_all_semantic"] == 0.725
    assert row["median_error_inferred_m"] == 0.10
    empty = _flat({})
    assert set(empty) == set(row) and all(v is None for v in empty.values())
    bare = _flat(_summary(10, 100, per_class=False))
    assert bare["ratio"] == 10.0 and bare["accurate_voxels_standard"] is None


def test_table_i_rows_paper_numbers_ratios_and_cross_ratio() -> None:
    _, groups, markdown = sweep_tables(_outcomes())
    assert [g["protocol"] for g in groups] == ["default"] * 2 + ["paper"] * 2
    assert "default: keyframes.spacing_m=2" in markdown
    assert "accurate_voxels_piling_standard" in markdown
    rows = table_i_rows(groups, ["default", "paper"])
    assert [(r["protocol"], r["spacing_m"], r["map"]) for r in rows[:4]] == [
        ("default", "4", "standard"),
        ("default", "4", "semantic"),
        ("default", "2", "standard"),
        ("default", "2", "semantic"),
    ]
    d4s, d4m = rows[0], rows[1]
    assert d4s["voxels_mean"] == 200 and d4s["voxels_std"] == pytest.approx(
        np.std([100, 300], ddof=1)
    )
    assert d4s["paper_voxels_mean"] == 2938.6 and d4s["paper_voxels_std"] == 984.18
    assert d4m["paper_voxels_mean"] == 60091.4
    assert d4m["ratio"] == pytest.approx(3000 / 200)  # ratio of the means, as the paper's
    assert d4m["paper_ratio"] == pytest.approx(60091.4 / 2938.6)
    assert d4m["inferred_over_fused"] == pytest.approx(0.10 / 0.04)
    assert d4s["ratio"] is None and d4s["inferred_over_fused"] is None
    p2m = next(
        r
        for r in rows
        if r["protocol"] == "paper" and r["spacing_m"] == "2" and r["map"] == "semantic"
    )
    assert p2m["paper_voxels_mean"] == 68422.2 and p2m["voxels_mean"] == 40000
    cross = {r["protocol"]: r for r in cross_ratio_rows(groups, ["default", "paper"])}
    assert cross["default"]["ratio"] == pytest.approx(3000 / 500)
    assert cross["paper"]["ratio"] == pytest.approx(20000 / 3000)
    assert cross["paper"]["paper_ratio"] == pytest.approx(60091.4 / 3549.4)
    assert f"{PAPER_CROSS_RATIO:.1f}" == "16.9"
    # accurate structure voxels: semantic at 4 m (210) over standard at 2 m (24)
    assert cross["default"]["accurate_ratio"] == pytest.approx(210 / 24)


def test_class_rows_mean_over_trials_and_pilings_together() -> None:
    runs = [o.to_json() for o in _outcomes()]
    rows = class_rows(runs, ["default", "paper"])
    cells = [(r["protocol"], r["spacing_m"]) for r in rows]
    assert list(dict.fromkeys(cells)) == [
        ("default", "4"),
        ("default", "2"),
        ("paper", "4"),
        ("paper", "2"),
    ]
    d4 = {r["class"]: r for r in rows if (r["protocol"], r["spacing_m"]) == ("default", "4")}
    assert list(d4) == [
        "cylindrical_piling",
        "rectangular_piling",
        "pilings (both)",
        "seafloor",
        "all_structure",
    ]
    cyl = d4["cylindrical_piling"]
    assert cyl["runs"] == 2 and cyl["standard_voxels"] == 15  # (10 + 20) / 2
    assert cyl["semantic_voxels"] == 300 and cyl["ratio"] == pytest.approx(20.0)
    assert cyl["standard_accurate_voxels"] == 8 and cyl["accurate_ratio"] == pytest.approx(150 / 8)
    assert cyl["median_error_fused_m"] == 0.05 and cyl["median_error_inferred_m"] == 0.09
    both = d4["pilings (both)"]
    assert both["standard_voxels"] == pytest.approx(15 + 30)
    assert both["semantic_accurate_voxels"] == 210
    assert both["completeness_semantic"] == pytest.approx((0.5 * 100 + 0.8 * 300) / 400)
    assert both["median_error_fused_m"] is None
    assert cyl["gain_share"] == pytest.approx((300 - 15) / ((1900 + 3700) / 2))
    assert class_rows([o.to_json() for o in _outcomes()][:0]) == []


def test_assigned_class_rows_mean_the_error_budget_over_trials() -> None:
    runs = [o.to_json() for o in _outcomes()]
    rows = assigned_class_rows(runs, ["default", "paper"])
    d4 = {r["class"]: r for r in rows if (r["protocol"], r["spacing_m"]) == ("default", "4")}
    assert list(d4) == ["cylindrical_piling", "rectangular_piling", "unknown"]  # no sums
    cyl = d4["cylindrical_piling"]
    assert cyl["runs"] == 2 and cyl["inferred_over_fused"] == pytest.approx(1.5)  # (1 + 2) / 2
    assert cyl["inferred_median_error_m"] == pytest.approx(0.075)
    assert d4["unknown"]["inferred_over_fused"] is None
    assert d4["unknown"]["fused_median_error_m"] == pytest.approx(0.08)
    assert assigned_class_rows(runs[:0]) == []


def _errors_file(path: Path, fused: np.ndarray, inferred: np.ndarray) -> dict[str, str]:
    path.mkdir(parents=True)
    table = pa.table(
        {
            "source": ["fused"] * len(fused) + ["inferred"] * len(inferred),
            "error_m": np.concatenate([fused, inferred]),
        }
    )
    pq.write_table(table, path / "errors.parquet")
    return {"stage": "evaluate", "path": str(path), "status": "computed"}


def test_box_stats_and_pooled_errors(tmp_path: Path) -> None:
    e = np.concatenate([np.linspace(0.0, 0.1, 101), [5.0]])
    stats = box_stats(e)
    assert stats["n"] == 102 and stats["whishi_m"] == pytest.approx(0.1)
    assert stats["outliers_pct"] == pytest.approx(100 / 102)
    assert box_stats([]) == {"n": 0}
    a = _errors_file(tmp_path / "a", np.full(600, 0.01), np.full(400, 0.2))
    b = _errors_file(tmp_path / "b", np.full(300, 0.03), np.full(700, 0.3))
    runs = [
        {
            "protocol": "paper",
            "overrides": {"keyframes.spacing_m": "4.0"},
            "status": "ok",
            "stages": [s],
        }
        for s in (a, b)
    ]
    pooled = pooled_errors(runs)
    cell = pooled[("paper", "4")]
    assert cell["trials"] == 2 and cell["step"] == 1
    assert len(cell["standard"]) == 900 and len(cell["semantic"]) == 2000
    small = pooled_errors(runs, max_points=500)[("paper", "4")]
    assert small["step"] == 4 and len(small["semantic"]) == 500


def test_write_study_table_figure_and_json(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    stages = {
        (p, s, t): [
            _errors_file(
                tmp_path / "store" / f"{p}-{s}-{t}",
                rng.gamma(2.0, 0.02, 500),
                rng.gamma(2.0, 0.04, 2000),
            )
        ]
        for p in ("default", "paper")
        for s in ("4", "2")
        for t in (0, 1)
    }
    out = tmp_path / "results"
    protocols = [{"name": "default", "config": None}, {"name": "paper", "config": "paper.yaml"}]
    doc = write_study(
        _outcomes(stages), out, protocols=protocols, header=["Trials: 2."], started=0.0
    )
    text = (out / "table_i.md").read_text()
    assert doc["table_i"] == text and json.loads((out / "study.json").read_text())["wall_s"] > 0
    for needle in (
        "| default | 4 m | standard | 2 | 200 ± 141 | 2938.6 ± 984.2 |",
        "| default | 4 m | semantic | 2 | 3000 ± 1414 | 60091.4 ± 20038.1 | 15.0x | 20.4x |",
        "| paper | 2 m | semantic | 2 | 40000 ± 14142 | 68422.2 ± 25518.4 | 13.3x | 19.3x |",
        "| default | 3000 | 500 | 6.0x | 16.9x | 8.8x |",
        "| paper | 20000 | 3000 | 6.7x | 16.9x |",
        "### paper, 2 m keyframes",
        "| pilings (both) | 45 | 450 | 10.0x |",
        "| 2.50x |",  # median error inferred / fused
        "## Error by assigned class",
        "| default | 4 m | cylindrical_piling | 2 | 0.050 | 0.075 | 1.50x |",
        "Trials: 2.",
    ):
        assert needle in text, needle
    assert text.index("| default | 4 m |") < text.index("| paper | 4 m |")
    boxes = doc["study"]["errors"]
    assert [(r["protocol"], r["spacing_m"], r["map"]) for r in boxes][:2] == [
        ("default", "4", "standard"),
        ("default", "4", "semantic"),
    ]
    assert boxes[0]["n"] == 1000 and boxes[1]["n"] == 5000
    assert boxes[1]["median_m"] > boxes[0]["median_m"]
    png = out / "fig4_errors.png"
    assert png.read_bytes()[:8] == PNG and png.stat().st_size > 5000
    assert (out / "sweep.parquet").is_file() and (out / "table.md").is_file()
    assert "| default | trial1.mcap | 4 m | ok | 2.5 | 1 / 0 |" in text


def test_write_study_without_per_class_or_errors(tmp_path: Path) -> None:
    outcomes = [
        RunOutcome(
            "/d/t.mcap", {"keyframes.spacing_m": "4"}, "ok", 1.0, _summary(10, 100, per_class=False)
        ),
        RunOutcome("/d/t.mcap", {"keyframes.spacing_m": "2"}, "failed", 0.5, error="boom\nmore"),
    ]
    doc = write_study(outcomes, tmp_path / "r", protocols=[{"name": "default", "config": None}])
    text = doc["table_i"]
    assert "## Per class" not in text and "Fig. 4 analogue" not in text
    assert not (tmp_path / "r" / "fig4_errors.png").exists()
    assert "| default | 4 m | semantic | 1 | 100 ± 0 | 60091.4 ± 20038.1 | 10.0x |" in text
    assert "| default | t.mcap | 2 m | failed | 0.5 | 0 / 0 | boom |" in text


def test_study_rejects_a_taken_protocol_name(tmp_path: Path) -> None:
    cfg = tmp_path / "default.yaml"
    cfg.write_text("keyframes: {}\n")
    res = CliRunner().invoke(app, ["study", "--config", str(cfg), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "already taken" in res.stderr
    res = CliRunner().invoke(app, ["study", "--no-default", "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "--config" in res.stderr


@pytest.mark.slow
def test_study_cli_default_and_a_config_side_by_side(tmp_path: Path) -> None:
    """One tiny trial at 4 m under the defaults and under a config: both in one table."""
    protocol = tmp_path / "loose.yaml"
    protocol.write_text("evaluate:\n  tolerance_m: 0.2\n")
    cheap = [
        "training.sets=[{scene: pier, seed: 7, goals: 3, duration_s: 70}, {scene: tiny, seed: 11, goals: 3, duration_s: 60}]",
        "training.procedural=null",
        f"training.directory={tmp_path / 'training'}",
        "train.epochs=8",
        "classify.mc_passes=8",
    ]
    out = tmp_path / "study"
    args = [
        "study", "--trials", "1", "--goals", "2", "--duration-s", "45", "--scene", "tiny",
        "--spacings", "4", "--config", str(protocol), *(a for f in cheap for a in ("--fix", f)),
        "--out", str(out), "--store", str(tmp_path / "store"), "--json",
    ]  # fmt: skip
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert [p["name"] for p in doc["protocols"]] == ["default", "loose"]
    runs = {r["protocol"]: r for r in doc["runs"]}
    assert set(runs) == {"default", "loose"} and {r["status"] for r in runs.values()} == {"ok"}
    # the protocol file as read once, kept with the results (an edit meanwhile changes nothing)
    kept = Path(runs["loose"]["config_path"])
    assert kept == (out / "results" / "protocols" / "loose.yaml").resolve()
    assert kept.read_bytes() == protocol.read_bytes() and runs["default"]["config_path"] is None
    assert all(r["seconds"] > 0 for r in runs.values()) and doc["wall_s"] > 0
    text = (out / "results" / "table_i.md").read_text()
    assert "| default | 4 m | semantic | 1 |" in text and "| loose | 4 m | semantic | 1 |" in text
    assert "60091.4 ± 20038.1" in text and "16.9x" in text
    assert "| loose | 4 m | standard |" in text.split("## Absolute point error")[1]
    png = out / "results" / "fig4_errors.png"
    assert png.read_bytes()[:8] == PNG
    assert json.loads((out / "results" / "study.json").read_text())["table_i"] == text
