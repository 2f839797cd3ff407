"""The headline map error (`sonarmap.stages.evaluate.headline`) in sweep and study tables.

A run's `summary.metrics.headline` says how its leading median error was obtained
(SE(2)-aligned SLAM map, ground-truth poses, or raw). Sweep rows carry it as columns
beside the raw medians; a table labels the headline column by the frame its runs share.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

__all__ = ["FRAME_WORDS", "frame_of", "headline_columns", "headline_header", "shared_frame"]

FRAME_WORDS: dict[str, str] = {
    "aligned": "SE(2)-aligned",
    "ground_truth_poses": "ground-truth poses",
    "raw": "raw, no ground-truth poses to align",
    "mixed": "mixed: aligned or ground-truth poses per run",
}
"""How a table names each headline frame."""


def _headline(summary: Mapping[str, Any]) -> Mapping[str, Any]:
    return (summary.get("metrics") or {}).get("headline") or {}


def headline_columns(summary: Mapping[str, Any]) -> dict[str, float | None]:
    """{median_error_headline_standard_m, ..._semantic_m, alignment_rotation_deg} of a run.

    Without a headline (an evaluate artifact older than the headline, or no ground
    truth) every value is None.
    """
    head = _headline(summary)
    median = head.get("median_m") or {}
    return {
        "median_error_headline_standard_m": median.get("standard"),
        "median_error_headline_semantic_m": median.get("semantic"),
        "alignment_rotation_deg": head.get("rotation_deg"),
    }


def frame_of(summary: Mapping[str, Any]) -> str | None:
    """The headline frame of one run's summary ("aligned", ... or None)."""
    frame = _headline(summary).get("frame")
    return None if frame is None else str(frame)


def shared_frame(frames: Iterable[str | None]) -> str | None:
    """The one frame all runs share, "mixed" when they differ, None when none reported."""
    found = {f for f in frames if f is not None}
    if not found:
        return None
    return found.pop() if len(found) == 1 else "mixed"


def headline_header(column: str, frame: str | None) -> str:
    """A table header naming the headline column's frame (other columns unchanged)."""
    if not column.startswith("median_error_headline_") or frame is None:
        return column
    name = column.removeprefix("median_error_headline_").removesuffix("_m")
    return f"median_error_{name}_m ({FRAME_WORDS.get(frame, frame)})"
