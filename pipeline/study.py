"""The simulation study's results: Table I beside the paper's, Fig. 4, per-class accounting.

`sonarmap study` maps the same simulated trials under one or more *protocols* (the
defaults, and each `--config FILE`, named by the file's stem) at each keyframe
spacing, with true poses. This module turns the sweep's outcomes into

- a Table I analogue per protocol with the paper's numbers beside ours (voxel counts,
  the semantic/standard ratio, median errors, the cross ratio "semantic at 4 m over
  standard at 2 m"),
- a per-class table from `summary.metrics.per_class` (where the evaluate stage reports
  it): voxels and accurate voxels of both maps, completeness, median errors,
- the Fig. 4 analogue `fig4_errors.png`: box plots of the absolute point error of both
  maps at each spacing, pooled over trials, from each run's `errors.parquet`,

written as `table_i.md` and `study.json` beside what `write_sweep` writes.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from pipeline.headline_columns import FRAME_WORDS, shared_frame
from pipeline.sweep import ALL_STRUCTURE, PILING_CLASSES, RunOutcome, per_class, stage_path

__all__ = [
    "DEFAULT_PROTOCOL",
    "PAPER_CROSS_RATIO",
    "PAPER_TABLE_I",
    "box_stats",
    "class_rows",
    "cross_ratio_rows",
    "error_rows",
    "plot_fig4",
    "pooled_errors",
    "render_markdown",
    "spacing_of",
    "table_i",
    "table_i_rows",
    "write_study",
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

MAX_POINTS_PER_BOX = 2_000_000
"""Fig. 4 pools every trial's points per box; above this many, every k-th point is kept."""


def spacing_of(overrides: Mapping[str, Any]) -> str:
    """The keyframe spacing of a run or group as the paper writes it ("4", "2", "2.5")."""
    value = overrides.get(SPACING_KEY)
    if value is None:
        return "?"
    try:
        return f"{float(value):g}"
    except (TypeError, ValueError):
        return str(value)


def _spacing_sort(spacing: str) -> float:
    try:
        return -float(spacing)
    except ValueError:
        return math.inf


def _protocol(item: Mapping[str, Any]) -> str:
    return str(item.get("protocol") or DEFAULT_PROTOCOL)


def _order(items: Sequence[Mapping[str, Any]], protocols: Sequence[str] | None) -> list[str]:
    seen = list(dict.fromkeys(_protocol(i) for i in items))
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
    cells: dict[str, dict[str, Mapping[str, Any]]] = {p: {} for p in _order(groups, protocols)}
    for g in groups:
        cells[_protocol(g)][spacing_of(g.get("overrides") or {})] = g
    return {
        p: dict(sorted(by_spacing.items(), key=lambda kv: _spacing_sort(kv[0])))
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
            key = (_protocol(run), spacing_of(run.get("overrides") or {}))
            cells.setdefault(key, []).append(run)
    order = _order([r for members in cells.values() for r in members], protocols)
    rows: list[dict[str, Any]] = []
    for protocol in order:
        spacings = sorted((s for p, s in cells if p == protocol), key=_spacing_sort)
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


def box_stats(error_m: Any) -> dict[str, float | int | None]:
    """Box-plot figures of absolute errors: quartiles, Tukey whiskers (1.5 IQR, at data
    points), 5/95 % percentiles and the share of points beyond the whiskers (the paper's
    "outliers not shown", 1.7-2.0 % in its Fig. 4)."""
    import numpy as np

    e = np.asarray(error_m, dtype=np.float64)
    if e.size == 0:
        return {"n": 0}
    q1, med, q3, p5, p95 = (float(v) for v in np.percentile(e, [25, 50, 75, 5, 95]))
    iqr = q3 - q1
    inside = e[(e >= q1 - 1.5 * iqr) & (e <= q3 + 1.5 * iqr)]
    lo, hi = (float(inside.min()), float(inside.max())) if inside.size else (q1, q3)
    return {
        "n": int(e.size),
        "mean_m": float(e.mean()),
        "median_m": med,
        "q1_m": q1,
        "q3_m": q3,
        "whislo_m": lo,
        "whishi_m": hi,
        "p5_m": p5,
        "p95_m": p95,
        "outliers_pct": 100.0 * float(((e < lo) | (e > hi)).mean()),
    }


def pooled_errors(
    runs: Sequence[Mapping[str, Any]], max_points: int = MAX_POINTS_PER_BOX
) -> dict[tuple[str, str], dict[str, Any]]:
    """{(protocol, spacing): {"standard": errors, "semantic": errors}} over all trials.

    Reads `error_m` and `source` of each successful run's evaluate `errors.parquet`
    (standard = the fused points, semantic = all). Above `max_points` per cell, every
    k-th point of every trial is kept (deterministic, trials keep their weight).
    """
    import numpy as np
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    files: dict[tuple[str, str], list[Path]] = {}
    for run in runs:
        path = stage_path(run.get("stages") or [], "evaluate")
        if run.get("status") != "ok" or path is None or not (path / "errors.parquet").is_file():
            continue
        key = (_protocol(run), spacing_of(run.get("overrides") or {}))
        files.setdefault(key, []).append(path / "errors.parquet")
    pooled: dict[tuple[str, str], dict[str, Any]] = {}
    for key, paths in files.items():
        total = sum(pq.ParquetFile(p).metadata.num_rows for p in paths)
        step = max(1, math.ceil(total / max_points))
        standard, semantic = [], []
        for p in paths:
            table = pq.read_table(p, columns=["error_m", "source"])
            err = table.column("error_m").to_numpy().astype(np.float32)[::step]
            fused = pc.equal(table.column("source"), "fused").to_numpy(zero_copy_only=False)
            fused = fused[::step]
            standard.append(err[fused])
            semantic.append(err)
        pooled[key] = {
            "standard": np.concatenate(standard),
            "semantic": np.concatenate(semantic),
            "trials": len(paths),
            "step": step,
        }
    return pooled


def error_rows(
    pooled: Mapping[tuple[str, str], Mapping[str, Any]], protocols: Sequence[str] | None = None
) -> list[dict[str, Any]]:
    """Box statistics per protocol x spacing x map (what fig4_errors.png draws)."""
    order = _order([{"protocol": p} for p, _ in pooled], protocols)
    rows = []
    for protocol in order:
        for spacing in sorted((s for p, s in pooled if p == protocol), key=_spacing_sort):
            cell = pooled[(protocol, spacing)]
            for name in MAPS:
                rows.append(
                    {
                        "protocol": protocol,
                        "spacing_m": spacing,
                        "map": name,
                        "trials": cell.get("trials"),
                        "subsample_step": cell.get("step", 1),
                        **box_stats(cell[name]),
                    }
                )
    return rows


COLOURS = {"standard": "#d4a017", "semantic": "#1f5fbf"}
"""The paper's Fig. 4: gold for the benchmark (standard map), blue for the proposed one."""


def plot_fig4(rows: Sequence[Mapping[str, Any]], path: Path) -> None:
    """One panel per protocol; per spacing (widest left, as in the paper) a gold box for
    the standard map and a blue one for the semantic map. Whiskers at 1.5 IQR, outliers
    not drawn (their share is printed under each box)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    drawn = [r for r in rows if r.get("n")]
    protocols = list(dict.fromkeys(r["protocol"] for r in drawn))
    fig, axes = plt.subplots(
        1,
        max(1, len(protocols)),
        figsize=(max(4.5, 3.6 * len(protocols)), 4.2),
        sharey=True,
        squeeze=False,
    )
    for ax, protocol in zip(axes[0], protocols, strict=False):
        mine = [r for r in drawn if r["protocol"] == protocol]
        spacings = list(dict.fromkeys(r["spacing_m"] for r in mine))
        for i, spacing in enumerate(spacings):
            for j, name in enumerate(MAPS):
                r = next((x for x in mine if x["spacing_m"] == spacing and x["map"] == name), None)
                if r is None:
                    continue
                stats = {
                    "med": r["median_m"],
                    "q1": r["q1_m"],
                    "q3": r["q3_m"],
                    "whislo": r["whislo_m"],
                    "whishi": r["whishi_m"],
                    "mean": r["mean_m"],
                    "label": "",
                }
                pos = i + (j - 0.5) * 0.38
                artists = ax.bxp(
                    [stats],
                    positions=[pos],
                    widths=0.32,
                    showfliers=False,
                    patch_artist=True,
                    medianprops={"color": "black"},
                )
                for box in artists["boxes"]:
                    box.set_facecolor(COLOURS[name])
                ax.annotate(
                    f"{r['outliers_pct']:.1f}%",
                    (pos, r["whishi_m"]),
                    textcoords="offset points",
                    xytext=(0, 3),
                    ha="center",
                    fontsize=7,
                )
        ax.set_xticks(range(len(spacings)), [f"{s} m keyframes" for s in spacings])
        ax.set_xlim(-0.7, len(spacings) - 0.3)
        ax.set_title(protocol)
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel("absolute error to the true mesh [m]")
    top = max((float(r["whishi_m"]) for r in drawn), default=1.0)
    axes[0][0].set_ylim(0.0, 1.12 * top if top > 0 else 1.0)
    fig.legend(
        handles=[
            Patch(facecolor=COLOURS["standard"], label="standard map (fused)"),
            Patch(facecolor=COLOURS["semantic"], label="semantic map (fused + inferred)"),
        ],
        fontsize=8,
        loc="lower center",
        ncol=2,
    )
    fig.suptitle("Fig. 4 analogue: point error (whiskers 1.5 IQR; % = outliers not shown)")
    fig.tight_layout(rect=(0.0, 0.06, 1.0, 1.0))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _num(value: float | None, fmt: str = ".0f", suffix: str = "") -> str:
    return "-" if value is None else f"{value:{fmt}}{suffix}"


def _pm(mean: float | None, std: float | None, fmt: str = ".0f") -> str:
    if mean is None:
        return "-"
    return f"{mean:{fmt}} ± {std:{fmt}}" if std is not None else f"{mean:{fmt}}"


def _table_i_md(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    frame = shared_frame(r.get("headline_frame") for r in rows)
    # The headline median leads; a raw column follows only where the two differ.
    raw_too = frame in ("aligned", "mixed")
    words = f", {FRAME_WORDS[frame]}" + ("; mean rotation" if raw_too else "") if frame else ""
    head = f"median error m (ours{words})"
    lines = [
        "| protocol | spacing | map | runs | voxels (ours, mean ± std) | voxels (paper) "
        f"| semantic/standard (ours) | (paper) | {head} "
        + ("| raw median error m (ours) " if raw_too else "")
        + "| median error inferred / fused (ours) |",
        "|---|---|---|---|---|---|---|---|---|" + ("---|" if raw_too else "") + "---|",
    ]
    for r in rows:
        lead = _num(r.get("median_error_headline_m") if frame else r["median_error_m"], ".3f")
        rotation = r.get("alignment_rotation_deg")
        if raw_too and rotation is not None:
            lead += f" ({rotation:.2f}°)"
        lines.append(
            f"| {r['protocol']} | {r['spacing_m']} m | {r['map']} | {r['runs']} "
            f"| {_pm(r['voxels_mean'], r['voxels_std'])} "
            f"| {_pm(r['paper_voxels_mean'], r['paper_voxels_std'], '.1f')} "
            f"| {_num(r['ratio'], '.1f', 'x') if r['map'] == 'semantic' else ''} "
            f"| {_num(r['paper_ratio'], '.1f', 'x') if r['map'] == 'semantic' else ''} "
            f"| {lead} "
            + (f"| {_num(r['median_error_m'], '.3f')} " if raw_too else "")
            + f"| {_num(r['inferred_over_fused'], '.2f', 'x') if r['map'] == 'semantic' else ''} |"
        )
    return lines


def table_i(groups: Sequence[Mapping[str, Any]], protocols: Sequence[str] | None = None) -> str:
    """Markdown of Table I alone: our figures beside the paper's."""
    return "\n".join(_table_i_md(table_i_rows(groups, protocols))) + "\n"


def render_markdown(
    study: Mapping[str, Any], runs: Sequence[Mapping[str, Any]], header: Sequence[str] = ()
) -> str:
    """table_i.md: Table I, the cross ratio, Fig. 4's figures, the per-class table, runs."""
    out: list[str] = [
        "# Table I analogue (McConnell & Englot, ICRA 2021)",
        "",
        *header,
        "",
        "10 cm voxels of the standard map (fused points) and the semantic map (fused +",
        "inferred), true poses (`slam.mode=ground_truth`), mean ± std over trials. The",
        "paper: 10 trials of 20 random goals in its Gazebo marina.",
        "",
        *_table_i_md(study["table_i"]),
        "",
        "## Semantic at 4 m over standard at 2 m",
        "",
        "| protocol | semantic 4 m (ours) | standard 2 m (ours) | ratio (ours) | ratio (paper) "
        "| accurate structure voxels ratio (ours) |",
        "|---|---|---|---|---|---|",
    ]
    for r in study["cross_ratio"]:
        out.append(
            f"| {r['protocol']} | {_num(r['semantic_4m'])} | {_num(r['standard_2m'])} "
            f"| {_num(r['ratio'], '.1f', 'x')} | {r['paper_ratio']:.1f}x "
            f"| {_num(r['accurate_ratio'], '.1f', 'x')} |"
        )
    errors = study.get("errors") or []
    if errors:
        out += [
            "",
            "## Absolute point error (Fig. 4 analogue: fig4_errors.png)",
            "",
            "Distance of every map point to the true mesh, all trials pooled. The paper's",
            "outliers beyond the whiskers: 1.7-2.0 % of each set.",
            "",
            "| protocol | spacing | map | points | median m | q1-q3 m | whiskers m (1.5 IQR) "
            "| p95 m | outliers beyond whiskers |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for r in errors:
            if not r.get("n"):
                out.append(f"| {r['protocol']} | {r['spacing_m']} m | {r['map']} | 0 |||||")
                continue
            sub = f" (every {r['subsample_step']}th)" if r.get("subsample_step", 1) > 1 else ""
            out.append(
                f"| {r['protocol']} | {r['spacing_m']} m | {r['map']} | {r['n']}{sub} "
                f"| {r['median_m']:.3f} | {r['q1_m']:.3f}-{r['q3_m']:.3f} "
                f"| {r['whislo_m']:.3f}-{r['whishi_m']:.3f} | {r['p95_m']:.3f} "
                f"| {r['outliers_pct']:.1f} % |"
            )
    classes = study.get("per_class") or []
    if classes:
        out += [
            "",
            "## Per class",
            "",
            "Mean over the trials that report the class; a voxel is accurate when a point in",
            "it lies within the tolerance of the true mesh; completeness is the share of the",
            "class's visible surface samples within the tolerance of the map;",
            f"{PILINGS_ROW}: the two piling classes together. Last column: the class's",
            "semantic minus standard voxels over the whole map's.",
        ]
        cells = list(dict.fromkeys((r["protocol"], r["spacing_m"]) for r in classes))
        for protocol, spacing in cells:
            first = next(
                r for r in classes if (r["protocol"], r["spacing_m"]) == (protocol, spacing)
            )
            out += [
                "",
                f"### {protocol}, {spacing} m keyframes (tolerance {first.get('tolerance_m')} m, "
                f"frame {first.get('frame')})",
                "",
                "| class | standard voxels | semantic voxels | ratio "
                "| standard accurate voxels | semantic accurate voxels | accurate ratio "
                "| completeness std → sem | median error fused m | median error inferred m "
                "| share of the map's voxel gain |",
                "|---|---|---|---|---|---|---|---|---|---|---|",
            ]
            for r in classes:
                if (r["protocol"], r["spacing_m"]) != (protocol, spacing):
                    continue
                out.append(
                    f"| {r['class']} | {_num(r['standard_voxels'])} "
                    f"| {_num(r['semantic_voxels'])} | {_num(r['ratio'], '.1f', 'x')} "
                    f"| {_num(r['standard_accurate_voxels'])} "
                    f"| {_num(r['semantic_accurate_voxels'])} "
                    f"| {_num(r['accurate_ratio'], '.1f', 'x')} "
                    f"| {_num(r['completeness_standard'], '.3f')} → "
                    f"{_num(r['completeness_semantic'], '.3f')} "
                    f"| {_num(r['median_error_fused_m'], '.3f')} "
                    f"| {_num(r['median_error_inferred_m'], '.3f')} "
                    f"| {_num(None if r['gain_share'] is None else 100 * r['gain_share'], '.0f', ' %')} |"
                )
    out += [
        "",
        "## Runs",
        "",
        "| protocol | dataset | spacing | status | seconds | stages computed / cached | error |",
        "|---|---|---|---|---|---|---|",
    ]
    for run in runs:
        stages = run.get("stages") or []
        computed = sum(1 for s in stages if s.get("status") == "computed")
        out.append(
            f"| {_protocol(run)} | {Path(str(run.get('dataset', ''))).name} "
            f"| {spacing_of(run.get('overrides') or {})} m | {run.get('status')} "
            f"| {float(run.get('seconds') or 0.0):.1f} | {computed} / {len(stages) - computed} "
            f"| {(run.get('error') or '').splitlines()[0] if run.get('error') else ''} |"
        )
    if "wall_s" in study:
        out += ["", f"Study wall time: {study['wall_s']:.1f} s."]
    return "\n".join(out) + "\n"


def write_study(
    outcomes: Sequence[RunOutcome],
    out_dir: Path,
    *,
    protocols: Sequence[Mapping[str, Any]] = (),
    header: Sequence[str] = (),
    started: float | None = None,
) -> dict[str, Any]:
    """Write the sweep files, `table_i.md`, `fig4_errors.png` and `study.json`.

    `protocols` are {"name", "config"} in display order; `started` is the study's
    `time.perf_counter()` at its start (for the wall time in the table and document).
    Returns the `study --json` document: the sweep's, plus `protocols`, `study`
    (the tables' rows), `table_i` (the markdown) and `wall_s`.
    """
    from pipeline.sweep_output import write_sweep

    doc = write_sweep(outcomes, out_dir)
    names = [str(p["name"]) for p in protocols]
    pooled = pooled_errors(doc["runs"])
    study: dict[str, Any] = {
        "table_i": table_i_rows(doc["groups"], names),
        "cross_ratio": cross_ratio_rows(doc["groups"], names),
        "per_class": class_rows(doc["runs"], names),
        "errors": error_rows(pooled, names),
        "paper": {
            "table_i": {s: {k: list(v) for k, v in m.items()} for s, m in PAPER_TABLE_I.items()},
            "cross_ratio": PAPER_CROSS_RATIO,
        },
    }
    figure = out_dir / "fig4_errors.png"
    if any(r.get("n") for r in study["errors"]):
        plot_fig4(study["errors"], figure)
        study["figure"] = str(figure)
    if started is not None:
        study["wall_s"] = round(time.perf_counter() - started, 1)
    markdown = render_markdown(study, doc["runs"], header)
    (out_dir / "table_i.md").write_text(markdown)
    doc.update(protocols=[dict(p) for p in protocols], study=study, table_i=markdown)
    if "wall_s" in study:
        doc["wall_s"] = study["wall_s"]
    (out_dir / "study.json").write_text(json.dumps(doc, indent=2, sort_keys=True, default=str))
    return doc
