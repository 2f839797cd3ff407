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

import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from sonarmap.pipeline.experiments.headline_columns import FRAME_WORDS, shared_frame
from sonarmap.pipeline.experiments.study_fig4 import error_rows, plot_fig4, pooled_errors
from sonarmap.pipeline.experiments.study_tables import (
    PAPER_CROSS_RATIO,
    PAPER_TABLE_I,
    PILINGS_ROW,
    assigned_class_rows,
    class_rows,
    cross_ratio_rows,
    protocol_of,
    spacing_of,
    table_i_rows,
)
from sonarmap.pipeline.experiments.sweep import (
    RunOutcome,
)
from sonarmap.pipeline.formats.strict_json import dumps_strict

__all__ = ["render_markdown", "table_i", "write_study"]


def _num(value: float | None, fmt: str = ".0f", suffix: str = "") -> str:
    return "-" if value is None else f"{value:{fmt}}{suffix}"


def _pm(mean: float | None, std: float | None, fmt: str = ".0f") -> str:
    if mean is None:
        return "-"
    return f"{mean:{fmt}} ± {std:{fmt}}" if std is not None else f"{mean:{fmt}}"


def _row(*cells: object) -> str:
    """One markdown table row."""
    return "| " + " | ".join(str(c) for c in cells) + " |"


def _head(*names: str) -> list[str]:
    """A markdown table's header and separator rows."""
    return [_row(*names), "|" + "---|" * len(names)]


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


def _voxels(runs: Sequence[Mapping[str, Any]]) -> str:
    """The voxel sizes the runs mapped at ("10 cm"; "10 cm / 50 cm" when protocols differ)."""
    sizes = sorted(
        {
            float(size)
            for r in runs
            if (size := ((r.get("summary") or {}).get("metrics") or {}).get("voxel_size_m"))
        }
    )
    return " / ".join(f"{100 * v:g} cm" for v in sizes) or "10 cm"


def render_markdown(
    study: Mapping[str, Any], runs: Sequence[Mapping[str, Any]], header: Sequence[str] = ()
) -> str:
    """table_i.md: Table I, the cross ratio, Fig. 4's figures, the per-class table, runs."""
    out: list[str] = [
        "# Table I analogue (McConnell & Englot, ICRA 2021)",
        "",
        *header,
        "",
        f"{_voxels(runs)} voxels of the standard map (fused points) and the semantic map",
        "(fused + inferred), true poses (`slam.mode=ground_truth`), mean ± std over trials.",
        "The paper: 10 trials of 20 random goals in its Gazebo marina, 10 cm voxels.",
        "",
        *_table_i_md(study["table_i"]),
        "",
        "## Semantic at 4 m over standard at 2 m",
        "",
        *_head(
            "protocol", "semantic 4 m (ours)", "standard 2 m (ours)", "ratio (ours)",
            "ratio (paper)", "accurate structure voxels ratio (ours)",
        ),
    ]  # fmt: skip
    out += [
        _row(
            r["protocol"], _num(r["semantic_4m"]), _num(r["standard_2m"]),
            _num(r["ratio"], ".1f", "x"), f"{r['paper_ratio']:.1f}x",
            _num(r["accurate_ratio"], ".1f", "x"),
        )
        for r in study["cross_ratio"]
    ]  # fmt: skip
    errors = study.get("errors") or []
    if errors:
        out += [
            "",
            "## Absolute point error (Fig. 4 analogue: fig4_errors.png)",
            "",
            "Distance of every map point to the true mesh, all trials pooled. The paper's",
            "outliers beyond the whiskers: 1.7-2.0 % of each set.",
            "",
            *_head(
                "protocol", "spacing", "map", "points", "median m", "q1-q3 m",
                "whiskers m (1.5 IQR)", "p95 m", "outliers beyond whiskers",
            ),
        ]  # fmt: skip
        for r in errors:
            cell = (r["protocol"], f"{r['spacing_m']} m", r["map"])
            if not r.get("n"):
                out.append(_row(*cell, 0, "", "", "", "", ""))
                continue
            sub = f" (every {r['subsample_step']}th)" if r.get("subsample_step", 1) > 1 else ""
            out.append(
                _row(
                    *cell, f"{r['n']}{sub}", f"{r['median_m']:.3f}",
                    f"{r['q1_m']:.3f}-{r['q3_m']:.3f}", f"{r['whislo_m']:.3f}-{r['whishi_m']:.3f}",
                    f"{r['p95_m']:.3f}", f"{r['outliers_pct']:.1f} %",
                )
            )  # fmt: skip
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
                *_head(
                    "class", "standard voxels", "semantic voxels", "ratio",
                    "standard accurate voxels", "semantic accurate voxels", "accurate ratio",
                    "completeness std → sem", "median error fused m", "median error inferred m",
                    "share of the map's voxel gain",
                ),
            ]  # fmt: skip
            out += [
                _row(
                    r["class"], _num(r["standard_voxels"]), _num(r["semantic_voxels"]),
                    _num(r["ratio"], ".1f", "x"), _num(r["standard_accurate_voxels"]),
                    _num(r["semantic_accurate_voxels"]), _num(r["accurate_ratio"], ".1f", "x"),
                    f"{_num(r['completeness_standard'], '.3f')} → "
                    f"{_num(r['completeness_semantic'], '.3f')}",
                    _num(r["median_error_fused_m"], ".3f"),
                    _num(r["median_error_inferred_m"], ".3f"),
                    _num(None if r["gain_share"] is None else 100 * r["gain_share"], ".0f", " %"),
                )
                for r in classes
                if (r["protocol"], r["spacing_m"]) == (protocol, spacing)
            ]  # fmt: skip
    budget = study.get("assigned_classes") or []
    if budget:
        out += [
            "",
            "## Error by assigned class",
            "",
            "The class the classifier gave each point's object; mean over trials of the",
            "fused and inferred medians and of their ratio (the per-class error budget).",
            "",
            *_head(
                "protocol", "spacing", "assigned class", "runs", "median error fused m",
                "median error inferred m", "inferred / fused",
            ),
        ]  # fmt: skip
        out += [
            _row(
                r["protocol"], f"{r['spacing_m']} m", r["class"], r["runs"],
                _num(r["fused_median_error_m"], ".3f"), _num(r["inferred_median_error_m"], ".3f"),
                _num(r["inferred_over_fused"], ".2f", "x"),
            )
            for r in budget
        ]  # fmt: skip
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
            f"| {protocol_of(run)} | {Path(str(run.get('dataset', ''))).name} "
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
    from sonarmap.pipeline.experiments.sweep_output import write_sweep

    doc = write_sweep(outcomes, out_dir)
    names = [str(p["name"]) for p in protocols]
    pooled = pooled_errors(doc["runs"])
    study: dict[str, Any] = {
        "table_i": table_i_rows(doc["groups"], names),
        "cross_ratio": cross_ratio_rows(doc["groups"], names),
        "per_class": class_rows(doc["runs"], names),
        "assigned_classes": assigned_class_rows(doc["runs"], names),
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
    (out_dir / "study.json").write_text(dumps_strict(doc))
    return doc
