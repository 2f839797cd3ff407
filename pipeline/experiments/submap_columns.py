"""Dense submaps (issue 21) in sweep tables: with-submaps over keyframes-only ratios.

A run mapped with `keyframes.submap_stride` > 0 reports `summary.metrics.submaps`
(`sonarmap.stages.evaluate.submaps`). Sweep rows carry its frame count and ratios as columns;
they are None for a run without submap frames, so a table leaves them out.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

__all__ = ["SUBMAP_FIGURES", "submap_columns"]

SUBMAP_FIGURES: dict[str, str] = {
    "voxels": "voxels",
    "accurate_voxels": "accurate",
    "median_error_m": "median_error",
}
"""Ratio figure of metrics["submaps"]["ratio"][map] -> its column's word."""


def submap_columns(summary: Mapping[str, Any]) -> dict[str, float | int | None]:
    """{submap_frames, submap_{voxels|accurate|median_error}_ratio_{standard|semantic}}.

    The median error ratio is of the headline median (SE(2)-aligned when the headline is).
    """
    block = (summary.get("metrics") or {}).get("submaps") or {}
    ratio = block.get("ratio") or {}
    row: dict[str, float | int | None] = {"submap_frames": block.get("frames")}
    for key, word in SUBMAP_FIGURES.items():
        for name in ("standard", "semantic"):
            row[f"submap_{word}_ratio_{name}"] = (ratio.get(name) or {}).get(key)
    return row
