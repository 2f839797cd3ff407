"""The study's tables as rows: Table I beside the paper's, the cross ratio, the per-class
accounting (from `summary.metrics.per_class`). `sonarmap.pipeline.experiments.study` renders them."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from sonarmap.pipeline.experiments.sweep import (
    ALL_STRUCTURE,
    PILING_CLASSES,
    per_class,
)

__all__ = [
    "CLASS_ORDER",
    "DEFAULT_PROTOCOL",
    "MAPS",
    "PAPER_CROSS_RATIO",
    "PAPER_TABLE_I",
    "PILINGS_ROW",
    "SPACING_KEY",
    "assigned_class_rows",
    "class_rows",
    "cross_ratio_rows",
    "spacing_of",
    "table_i_rows",
]


PAPER_TABLE_I: dict[str, dict[str, tuple[float, float]]] = {
    "4": {"standard": (2938.6, 984.18), "semantic": (60091.4, 20038.116)},
    "2": {"standard": (3549.4, 1144.72), "semantic": (68422.2, 25518.37)},
}
"""McConnell & Englot (ICRA 2021), Table I: mean and std of 10 cm voxel counts, 10 trials."""


PAPER_CROSS_RATIO = PAPER_TABLE_I["4"]["semantic"][0] / PAPER_TABLE_I["2"]["standard"][0]
"""The paper's headline: semantic mapping at 4 m over standard mapping at 2 m (16.9x)."""


DEFAULT_PROTOCOL = "default"
"""The name of the protocol that runs sonarmap's own defaults (no config file)."""


SPACING_KEY = "keyframes.spacing_m"


MAPS: tuple[str, ...] = ("standard", "semantic")


CLASS_ORDER: tuple[str, ...] = (
    "cylindrical_piling",
    "rectangular_piling",
    "seawall",
    "boat_hull",
    "truss",
)


PILINGS_ROW = "pilings (both)"
"""The two piling classes together (voxels summed, completeness weighted by samples)."""


def spacing_of(overrides: Mapping[str, Any]) -> str:
    """The keyframe spacing of a run or group as the paper writes it ("4", "2", "2.5")."""
    value = overrides.get(SPACING_KEY)
    if value is None:
        return "?"
    try:
        return f"{float(value):g}"
    except (TypeError, ValueError):
        return str(value)


def spacing_sort(spacing: str) -> float:
    try:
        return -float(spacing)
    except ValueError:
        return math.inf


def protocol_of(item: Mapping[str, Any]) -> str:
    return str(item.get("protocol") or DEFAULT_PROTOCOL)


def protocol_order(
    items: Sequence[Mapping[str, Any]], protocols: Sequence[str] | None
) -> list[str]:
    seen = list(dict.fromkeys(protocol_of(i) for i in items))
    given = [p for p in (protocols or ()) if p in seen]
    return given + [p for p in seen if p not in given]


def _mean(group: Mapping[str, Any] | None, key: str) -> float | None:
    value = ((group or {}).get(key) or {}).get("mean")
    return None if value is None else float(value)


def _std(group: Mapping[str, Any] | None, key: str) -> float | None:
    value = ((group or {}).get(key) or {}).get("std")
    return None if value is None else float(value)


def _ratio(num: float | None, den: float | None) -> float | None:
    return num / den if num is not None and den else None


def _by_cell(
    groups: Sequence[Mapping[str, Any]], protocols: Sequence[str] | None
) -> dict[str, dict[str, Mapping[str, Any]]]:
    """{protocol: {spacing: group}} in protocol order, spacings widest first."""
    cells: dict[str, dict[str, Mapping[str, Any]]] = {
        p: {} for p in protocol_order(groups, protocols)
    }
    for g in groups:
        cells[protocol_of(g)][spacing_of(g.get("overrides") or {})] = g
    return {
        p: dict(sorted(by_spacing.items(), key=lambda kv: spacing_sort(kv[0])))
        for p, by_spacing in cells.items()
    }


def table_i_rows(
    groups: Sequence[Mapping[str, Any]], protocols: Sequence[str] | None = None
) -> list[dict[str, Any]]:
    """One row per protocol x spacing x map: our mean ± std beside the paper's.

    `ratio` is semantic over standard of the mean voxel counts (as the paper's table
    gives it); `inferred_over_fused` is the mean median error of the inferred points
    over that of the fused points (the standard map), on the semantic row.
    """
    rows: list[dict[str, Any]] = []
    for protocol, by_spacing in _by_cell(groups, protocols).items():
        for spacing, g in by_spacing.items():
            paper = PAPER_TABLE_I.get(spacing, {})
            for name in MAPS:
                semantic = name == "semantic"
                p = paper.get(name)
                rows.append(
                    {
                        "protocol": protocol,
                        "spacing_m": spacing,
                        "map": name,
                        "runs": int(g.get("runs", 0)),
                        "voxels_mean": _mean(g, f"voxels_{name}"),
                        "voxels_std": _std(g, f"voxels_{name}"),
                        "paper_voxels_mean": p[0] if p else None,
                        "paper_voxels_std": p[1] if p else None,
                        "ratio": _ratio(_mean(g, "voxels_semantic"), _mean(g, "voxels_standard"))
                        if semantic
                        else None,
                        "paper_ratio": paper["semantic"][0] / paper["standard"][0]
                        if paper and semantic
                        else None,
                        "median_error_m": _mean(g, f"median_error_{name}_m"),
                        "median_error_headline_m": _mean(g, f"median_error_headline_{name}_m"),
                        "headline_frame": g.get("headline_frame"),
                        "alignment_rotation_deg": _mean(g, "alignment_rotation_deg"),
                        "inferred_over_fused": _ratio(
                            _mean(g, "median_error_inferred_m"),
                            _mean(g, "median_error_standard_m"),
                        )
                        if semantic
                        else None,
                        "accurate_voxels_mean": _mean(g, f"accurate_voxels_{name}"),
                    }
                )
    return rows


def cross_ratio_rows(
    groups: Sequence[Mapping[str, Any]], protocols: Sequence[str] | None = None
) -> list[dict[str, Any]]:
    """Per protocol: mean semantic voxels at 4 m over mean standard voxels at 2 m.

    `accurate_ratio` is the same for the accurate structure voxels (`all_structure`
    of the per-class accounting), where the evaluate stage reports them.
    """
    rows = []
    for protocol, by_spacing in _by_cell(groups, protocols).items():
        wide, dense = by_spacing.get("4"), by_spacing.get("2")
        sem4, std2 = _mean(wide, "voxels_semantic"), _mean(dense, "voxels_standard")
        rows.append(
            {
                "protocol": protocol,
                "semantic_4m": sem4,
                "standard_2m": std2,
                "ratio": _ratio(sem4, std2),
                "paper_ratio": PAPER_CROSS_RATIO,
                "accurate_ratio": _ratio(
                    _mean(wide, "accurate_voxels_semantic"),
                    _mean(dense, "accurate_voxels_standard"),
                ),
            }
        )
    return rows


def _class_order(names: set[str]) -> list[str]:
    known = [c for c in CLASS_ORDER if c in names]
    rest = sorted(names - set(CLASS_ORDER) - {"seafloor", ALL_STRUCTURE})
    order = known + rest + [c for c in ("seafloor", ALL_STRUCTURE) if c in names]
    if all(c in names for c in PILING_CLASSES):
        order.insert(order.index(PILING_CLASSES[-1]) + 1, PILINGS_ROW)
    return order


def _class_figures(classes: Mapping[str, Any], name: str) -> dict[str, float | None]:
    """One run's figures of one class (or of the pilings together)."""
    members = list(PILING_CLASSES) if name == PILINGS_ROW else [name]
    entries = [classes[c] for c in members if c in classes]

    def total(part: str, key: str) -> float | None:
        vals = [(e.get(part) or {}).get(key) for e in entries]
        found = [float(v) for v in vals if v is not None]
        return sum(found) if found else None

    out: dict[str, float | None] = {}
    for part in MAPS:
        out[f"{part}_voxels"] = total(part, "voxels")
        out[f"{part}_accurate_voxels"] = total(part, "accurate_voxels")
        out[f"{part}_points"] = total(part, "points")
        # Completeness of several classes: weighted by each one's visible samples.
        num = den = 0.0
        for e in entries:
            c, n = (e.get(part) or {}).get("completeness"), e.get("visible_samples") or 0
            if c is not None and n:
                num, den = num + float(c) * n, den + n
        if len(entries) == 1:
            c = (entries[0].get(part) or {}).get("completeness")
            out[f"completeness_{part}"] = None if c is None else float(c)
        else:
            out[f"completeness_{part}"] = num / den if den else None
    single = len(entries) == 1 and name != PILINGS_ROW
    first = entries[0] if single else {}
    out["median_error_fused_m"] = (first.get("standard") or {}).get("median_error_m")
    out["median_error_inferred_m"] = (first.get("inferred") or {}).get("median_error_m")
    out["inferred_points"] = total("inferred", "points")
    vs = [e.get("visible_samples") for e in entries if e.get("visible_samples") is not None]
    out["visible_samples"] = float(sum(vs)) if vs else None
    return out


def class_rows(
    runs: Sequence[Mapping[str, Any]], protocols: Sequence[str] | None = None
) -> list[dict[str, Any]]:
    """Per protocol x spacing x class: means over the successful trials that report it.

    `runs` are `RunOutcome.to_json()` documents. Empty when no run carries
    `summary.metrics.per_class`.
    """
    cells: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
    for run in runs:
        if run.get("status") == "ok" and per_class(run.get("summary") or {}):
            key = (protocol_of(run), spacing_of(run.get("overrides") or {}))
            cells.setdefault(key, []).append(run)
    order = protocol_order([r for members in cells.values() for r in members], protocols)
    rows: list[dict[str, Any]] = []
    for protocol in order:
        spacings = sorted((s for p, s in cells if p == protocol), key=spacing_sort)
        for spacing in spacings:
            members = cells[(protocol, spacing)]
            per_run = [per_class(r.get("summary") or {}) for r in members]
            meta = ((members[0].get("summary") or {}).get("metrics") or {}).get("per_class") or {}
            gains = [
                float(v["semantic"]) - float(v["standard"])
                for r in members
                if (v := (r.get("summary") or {}).get("voxels") or {}).get("semantic") is not None
                and v.get("standard") is not None
            ]
            gain = sum(gains) / len(gains) if gains else None
            names = set().union(*(set(c) for c in per_run))
            for name in _class_order(names):
                figures = [
                    _class_figures(c, name)
                    for c in per_run
                    if (name in c) or (name == PILINGS_ROW and any(p in c for p in PILING_CLASSES))
                ]
                row: dict[str, Any] = {
                    "protocol": protocol,
                    "spacing_m": spacing,
                    "class": name,
                    "runs": len(figures),
                    "frame": meta.get("frame"),
                    "tolerance_m": meta.get("tolerance_m"),
                    "voxel_size_m": meta.get("voxel_size_m"),
                }
                for column in figures[0]:
                    vals = [v for f in figures if (v := f[column]) is not None]
                    row[column] = sum(vals) / len(vals) if vals else None
                row["ratio"] = _ratio(row["semantic_voxels"], row["standard_voxels"])
                row["accurate_ratio"] = _ratio(
                    row["semantic_accurate_voxels"], row["standard_accurate_voxels"]
                )
                row["gain_share"] = (
                    _ratio(row["semantic_voxels"] - row["standard_voxels"], gain)
                    if row["semantic_voxels"] is not None and row["standard_voxels"] is not None
                    else None
                )
                rows.append(row)
    return rows


def assigned_class_rows(
    runs: Sequence[Mapping[str, Any]], protocols: Sequence[str] | None = None
) -> list[dict[str, Any]]:
    """Per protocol x spacing x assigned class: the fused and inferred median errors and
    their ratio (the per-class error budget), means over the trials that report them
    (`summary.metrics.per_class.assigned_classes`)."""
    cells: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
    for run in runs:
        metrics = (run.get("summary") or {}).get("metrics") or {}
        budget = (metrics.get("per_class") or {}).get("assigned_classes")
        if run.get("status") == "ok" and budget:
            cell = (protocol_of(run), spacing_of(run.get("overrides") or {}))
            cells.setdefault(cell, []).append(budget)
    order = protocol_order(
        [r for r in runs if (protocol_of(r), spacing_of(r.get("overrides") or {})) in cells],
        protocols,
    )
    rows: list[dict[str, Any]] = []
    for protocol in order:
        for spacing in sorted((s for p, s in cells if p == protocol), key=spacing_sort):
            budgets = cells[(protocol, spacing)]
            for name in _class_order(set().union(*(set(b) for b in budgets))):
                if name == PILINGS_ROW:  # a ratio of medians does not add up over classes
                    continue
                entries = [b[name] for b in budgets if name in b]
                row: dict[str, Any] = {
                    "protocol": protocol, "spacing_m": spacing, "class": name,
                    "runs": len(entries),
                }  # fmt: skip
                for key in (
                    "fused_median_error_m",
                    "inferred_median_error_m",
                    "inferred_over_fused",
                ):
                    vals = [float(v) for e in entries if (v := e.get(key)) is not None]
                    row[key] = sum(vals) / len(vals) if vals else None
                rows.append(row)
    return rows
