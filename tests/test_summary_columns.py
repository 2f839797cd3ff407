"""The run summary never cuts a header or a value: whole tables on a wide terminal,
plain `header=value` lines at 80 columns or when the output is not a terminal."""

from __future__ import annotations

import re
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
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], **env: str
) -> str:
    for name in ("COLUMNS", "FORCE_COLOR", "TTY_COMPATIBLE", "NO_COLOR"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    print_summary(_result(), SUMMARY)
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
    assert f"{STORE}/evaluate/{'a' * 64}" in out  # artifact paths whole
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
