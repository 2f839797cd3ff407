"""The run summary never cuts a header or a value: whole tables on a wide terminal,
plain `header=value` lines at 80 columns or when the output is not a terminal."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from sonarmap.pipeline.engine.run.runner import RunResult, StageResult
from sonarmap.pipeline.report_cli import print_summary
from sonarmap.pipeline.tables import plain_lines

STORE = "/home/researcher/field-campaigns/2026-harbour/store"
LABEL = "median error m, SE(2)-aligned (rotation -0.34°)"
SUMMARY: dict[str, Any] = {
    "voxels": {"standard": 128, "semantic": 204},
    "voxel_size_m": 0.1,
    "metrics": {
        "errors": {"standard": {"median_m": 0.057}, "semantic": {"median_m": 0.079}},
        "headline": {
            "frame": "aligned",
            "label": LABEL,
            "median_m": {"standard": 0.057, "semantic": 0.062},
        },
        "per_class": {
            "tolerance_m": 0.1,
            "classes": {
                "all_structure": {
                    "standard": {"accurate_voxels": 98, "completeness": 0.202},
                    "semantic": {"accurate_voxels": 153, "completeness": 0.267},
                }
            },
        },
        "submaps": {
            "stride": 4,
            "frames": 30,
            "frame": "aligned",
            "label": LABEL,
            "keyframes_only": {"standard": {"voxels": 128}, "semantic": {"voxels": 204}},
            "with_submaps": {"standard": {"voxels": 300}, "semantic": {"voxels": 410}},
            "ratio": {"standard": {"voxels": 2.34}, "semantic": {"voxels": 2.01}},
        },
    },
    "report": f"{STORE}/evaluate/{'e' * 64}/report.md",
}
WORDS = ("SE(2)-aligned", "completeness", "semantic/standard", "accurate voxels")


def _result() -> RunResult:
    stages = [
        StageResult(name, "k" * 64, "computed", 0.5, f"{STORE}/{name}/{'a' * 64}")
        for name in ("keyframes", "fuse", "evaluate")
    ]
    return RunResult("/data/dive.mcap", STORE, stages)


def _printed(
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    stages_listed: bool = False,
    **env: str,
) -> str:
    for name in ("COLUMNS", "FORCE_COLOR", "TTY_COMPATIBLE", "NO_COLOR"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    print_summary(_result(), SUMMARY, stages_listed=stages_listed)
    return re.sub(r"\x1b\[[0-9;]*m", "", capsys.readouterr().out)


@pytest.mark.parametrize(
    "env",
    [
        {},  # not a terminal: a log file, CI, `| tee`
        {"COLUMNS": "100"},  # not a terminal, a width too narrow for the tables
        {"COLUMNS": "80", "FORCE_COLOR": "1", "TTY_COMPATIBLE": "1"},  # an 80-column terminal
    ],
)
def test_summary_is_never_cut(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], env: dict[str, str]
) -> None:
    out = _printed(monkeypatch, capsys, **env)
    for word in WORDS:
        assert word in out
    assert LABEL in out
    assert "…" not in out
    assert f"artifacts: {STORE}/STAGE/KEY" in out  # the store whole, once
    assert "k" * 12 in out and "k" * 13 not in out  # each artifact by a short key
    assert "a" * 64 not in out
    assert SUMMARY["report"] in out  # on one line, copyable
    assert "standard, with submaps" in out and "semantic, ratio" in out


def test_a_wide_terminal_gets_the_whole_table(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    out = _printed(monkeypatch, capsys, COLUMNS="400", FORCE_COLOR="1", TTY_COMPATIBLE="1")
    assert "┃ map " in out  # rich tables, not the plain layout
    for word in WORDS:
        assert word in out
    assert "…" not in out


def test_plain_lines_keep_every_header_and_skip_empty_cells() -> None:
    lines = plain_lines(
        "Coverage",
        ("map", "voxels", "completeness"),
        [("standard", "12", ""), ("semantic", "", "")],
    )
    assert lines == ["Coverage", "standard: voxels=12", "semantic"]


def test_stages_listed_by_the_progress_are_not_listed_again(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    out = _printed(monkeypatch, capsys, stages_listed=True, COLUMNS="80")
    assert "computed" not in out and "k" * 12 not in out
    assert f"artifacts: {STORE}/STAGE/KEY" in out and "semantic/standard" in out


def test_a_log_file_names_each_stage_once(toy_env: list[Path], tmp_path: Path) -> None:
    """stdout and stderr into one file (`> log 2>&1`) at 80 columns: the progress lists
    each stage, the summary does not list them again."""
    log = tmp_path / "run.log"
    with log.open("w") as out:
        subprocess.run(
            [sys.executable, "-m", "sonarmap.pipeline", "run", str(toy_env[0]),
             "--store", str(tmp_path / "store")],
            stdout=out, stderr=subprocess.STDOUT, env={**os.environ, "COLUMNS": "80"},
            check=True,
        )
    lines = log.read_text().splitlines()
    for stage in ("source", "double", "summary", "count"):
        assert sum(re.search(rf"\b{stage}\b", line) is not None for line in lines) == 1, lines
    assert max(map(len, lines[:4])) <= 80, lines  # the stage lines do not wrap
