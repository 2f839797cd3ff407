"""Dense submaps (issue 21): the map of the keyframes alone beside the map with the
submap frames between them (`keyframes.submap_stride`, stage `submaps`).

map.parquet tells the two apart by `frame_id` (`sonarmap.schemas.submaps.KEYFRAME_FRAME_ID` for a
keyframe's own points, >= 0 for a submap frame's). Both variants are judged with the
figures evaluate already computes for the whole map, by the same functions:

- voxels: occupied voxels of each map (floor(x / size), as `voxelize` counts them);
- accurate voxels and completeness: the "all structure" row of the per-class
  accounting (`sonarmap.stages.evaluate.class_accounting`): voxels holding a structure point
  within the tolerance of the true surface, and the fraction of the visible structure
  surface within the tolerance of a map point. The visible surface is the keyframes'
  in both variants (the rule of `sonarmap.stages.kernels.mesh_metrics`), so completeness compares the
  two maps against the same samples;
- median error: the headline figure (`sonarmap.stages.evaluate.headline`: SE(2)-aligned when the
  headline is) and the raw one beside it;
- per class: the per-class accounting of each variant.

`ratio` is with-submaps over keyframes-only of every figure of both maps.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.schemas.map import MAP_NAMES
from sonarmap.schemas.submaps import KEYFRAME_FRAME_ID
from sonarmap.stages.evaluate.class_accounting import ALL_STRUCTURE
from sonarmap.stages.evaluate.headline import headline_errors
from sonarmap.stages.kernels.mesh_metrics import error_stats
from sonarmap.stages.kernels.voxels import map_xyz, voxel_keys

__all__ = ["FIGURES", "JudgedMap", "has_submap_rows", "submap_comparison", "submaps_markdown"]

FIGURES: tuple[str, ...] = (
    "points",
    "voxels",
    "accurate_voxels",
    "completeness",
    "median_error_m",
    "raw_median_error_m",
)
"""Figures of each map in each variant (and in `ratio`), in table order."""

ClassFigures = Callable[[pa.Table, np.ndarray, np.ndarray], Mapping[str, Any]]
"""(map rows, (n, 3) judged positions [m], (n,) judged errors [m]) -> the per-class
accounting of those rows (`class_accounting.per_class_metrics`, bound by the stage)."""


@dataclass(frozen=True)
class JudgedMap:
    """What evaluate computed for the whole map, row for row with map.parquet.

    Attributes:
        raw_error_m: (n,) distance of each point to the mesh at its mapped position [m].
        error_m: (n,) the same at the judged position (after the SE(2) alignment when
            there is one, else equal to raw_error_m) [m].
        xyz_m: (n, 3) judged positions [m].
        headline: metrics["headline"] (its frame and rotation are reused).
        per_class: metrics["per_class"] of the whole map.
        class_figures: the per-class accounting of a subset of rows.
    """

    raw_error_m: np.ndarray
    error_m: np.ndarray
    xyz_m: np.ndarray
    headline: Mapping[str, Any]
    per_class: Mapping[str, Any]
    class_figures: ClassFigures


def _frame_ids(map_table: pa.Table) -> np.ndarray:
    if "frame_id" not in map_table.column_names:
        return np.full(map_table.num_rows, KEYFRAME_FRAME_ID, np.int64)
    return np.asarray(map_table.column("frame_id").to_numpy(), np.int64)


def has_submap_rows(map_table: pa.Table) -> bool:
    """True when some map row was observed in a submap frame (frame_id >= 0)."""
    return bool((_frame_ids(map_table) != KEYFRAME_FRAME_ID).any())


def _medians(judged: JudgedMap, rows: np.ndarray, fused: np.ndarray) -> dict[str, Any]:
    """metrics["headline"]-shaped medians of the rows `rows`, in the headline's frame."""
    maps = {"standard": rows & fused, "semantic": rows}
    raw = {name: error_stats(judged.raw_error_m[m]) for name, m in maps.items()}
    aligned: dict[str, Any] | None = None
    if judged.headline.get("frame") == "aligned":
        aligned = {name: error_stats(judged.error_m[m]) for name, m in maps.items()}
        aligned["rotation_deg"] = judged.headline.get("rotation_deg")
    return headline_errors(raw, aligned, judged.headline.get("frame") == "ground_truth_poses")


def _variant(
    map_table: pa.Table, rows: np.ndarray, keys: np.ndarray, judged: JudgedMap | None
) -> dict[str, Any]:
    """Figures of both maps over the rows `rows` ({map: {figure: value}}, "per_class")."""
    fused = np.asarray(map_table.column("source").to_pylist(), dtype=object) == "fused"
    classes: Mapping[str, Any] = {}
    head: dict[str, Any] = {}
    if judged is not None:
        if rows.all():
            classes = judged.per_class.get("classes") or {}
        else:
            sub = map_table.filter(pa.array(rows))
            classes = judged.class_figures(sub, judged.xyz_m[rows], judged.error_m[rows])
            classes = classes.get("classes") or {}
        head = _medians(judged, rows, fused)
    whole = classes.get(ALL_STRUCTURE) or {}
    out: dict[str, Any] = {}
    for name, in_map in (("standard", rows & fused), ("semantic", rows)):
        out[name] = {
            "points": int(in_map.sum()),
            "voxels": int(np.unique(keys[in_map]).size),
            "accurate_voxels": (whole.get(name) or {}).get("accurate_voxels"),
            "completeness": (whole.get(name) or {}).get("completeness"),
            "median_error_m": (head.get("median_m") or {}).get(name),
            "raw_median_error_m": (head.get("raw_median_m") or {}).get(name),
        }
    if judged is not None:
        out["per_class"] = dict(classes)
    return out


def _ratio(num: Any, den: Any) -> float | None:
    return float(num) / float(den) if num is not None and den else None


def submap_comparison(
    map_table: pa.Table,
    voxel_size_m: float,
    stride: int | None,
    judged: JudgedMap | None,
) -> dict[str, Any]:
    """Keyframes-only vs with-submaps figures of both maps (see the module docstring).

    Args:
        map_table: map.parquet (`sonarmap.schemas.map.MAP_SCHEMA`), n rows.
        voxel_size_m: voxel edge [m] (voxelize's).
        stride: `keyframes.submap_stride` of the run (None when unknown).
        judged: evaluate's whole-map figures, or None without a ground-truth mesh (then
            only points and voxels are compared).

    Returns:
        {"stride", "frames": distinct submap frames in the map, "frame", "label",
        "keyframes_only": {map: {figure: value}, "per_class"?}, "with_submaps": {...},
        "ratio": {map: {figure: with / keyframes-only}}}.
    """
    frame_id = _frame_ids(map_table)
    keys = voxel_keys(np.floor(map_xyz(map_table, "semantic") / voxel_size_m))
    variants = {
        "keyframes_only": _variant(map_table, frame_id == KEYFRAME_FRAME_ID, keys, judged),
        "with_submaps": _variant(map_table, np.ones(len(frame_id), bool), keys, judged),
    }
    ratio = {
        name: {
            f: _ratio(variants["with_submaps"][name][f], variants["keyframes_only"][name][f])
            for f in FIGURES
        }
        for name in MAP_NAMES
    }
    head = judged.headline if judged is not None else {}
    return {
        "stride": stride,
        "frames": int(np.unique(frame_id[frame_id != KEYFRAME_FRAME_ID]).size),
        "frame": head.get("frame"),
        "label": head.get("label"),
        "tolerance_m": judged.per_class.get("tolerance_m") if judged is not None else None,
        **variants,
        "ratio": ratio,
    }


def _cell(value: Any, spec: str) -> str:
    return "-" if value is None else spec.format(value)


def _pair(kf: Mapping[str, Any], with_: Mapping[str, Any], key: str, spec: str) -> str:
    return f"{_cell(kf.get(key), spec)} / {_cell(with_.get(key), spec)}"


_SPECS = {"points": "{}", "voxels": "{}", "accurate_voxels": "{}", "completeness": "{:.3f}"}


def _class_lines(block: Mapping[str, Any]) -> list[str]:
    """Per-class rows (keyframes only / with submaps), or none without the accounting."""
    kf_classes = (block.get("keyframes_only") or {}).get("per_class") or {}
    with_classes = (block.get("with_submaps") or {}).get("per_class") or {}
    if not with_classes:
        return []
    lines = [
        "",
        "By true class (keyframes only / with submap frames):",
        "",
        "| class | map | voxels | accurate voxels | gain | completeness | median error m |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for cls, entry in with_classes.items():
        for name in MAP_NAMES:
            kf = (kf_classes.get(cls) or {}).get(name) or {}
            w = entry.get(name) or {}
            gain = _ratio(w.get("accurate_voxels"), kf.get("accurate_voxels"))
            lines.append(
                f"| {cls} | {name} | {_pair(kf, w, 'voxels', '{}')}"
                f" | {_pair(kf, w, 'accurate_voxels', '{}')} | {_cell(gain, '{:.2f}x')}"
                f" | {_pair(kf, w, 'completeness', '{:.3f}')}"
                f" | {_pair(kf, w, 'median_error_m', '{:.3f}')} |"
            )
    return lines


def submaps_markdown(block: Mapping[str, Any] | None) -> list[str]:
    """report.md lines of metrics["submaps"] (none when the run mapped no submap frames)."""
    if not block:
        return []
    aligned = block.get("frame") == "aligned"
    label = block.get("label") or "median error m"
    cols = ["map", "variant", *(f.replace("_", " ") for f in _SPECS), label]
    cols += ["raw median error m"] if aligned else []
    lines = [
        "## Dense submaps: keyframes only vs with submap frames",
        "",
        f"Submap stride {_cell(block.get('stride'), '{}')}: {block.get('frames')} submap frames"
        " between the keyframes are mapped too. Accurate voxels hold a structure point within"
        f" {_cell(block.get('tolerance_m'), '{}')} m of the true surface; completeness is of the"
        " structure surface visible from the keyframes, the same samples for both maps.",
        "",
        "| " + " | ".join(cols) + " |",
        "|---|---|" + "---:|" * (len(cols) - 2),
    ]
    medians = ["median_error_m", *(["raw_median_error_m"] if aligned else [])]
    for name in MAP_NAMES:
        for variant, words in (
            ("keyframes_only", "keyframes only"),
            ("with_submaps", "with submaps"),
        ):
            fig = (block.get(variant) or {}).get(name) or {}
            cells = [_cell(fig.get(f), spec) for f, spec in _SPECS.items()]
            cells += [_cell(fig.get(m), "{:.3f}") for m in medians]
            lines.append(f"| {name} | {words} | " + " | ".join(cells) + " |")
        ratio = (block.get("ratio") or {}).get(name) or {}
        cells = [_cell(ratio.get(f), "{:.2f}x") for f in (*_SPECS, *medians)]
        lines.append(f"| {name} | **ratio** | " + " | ".join(cells) + " |")
    return [*lines, *_class_lines(block), ""]
