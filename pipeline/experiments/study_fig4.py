"""The study's Fig. 4 analogue: box plots of the absolute point error of both maps at each
spacing and protocol, pooled over trials from each run's `errors.parquet`."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from sonarmap.pipeline.experiments.study_tables import (
    MAPS,
    protocol_of,
    protocol_order,
    spacing_of,
    spacing_sort,
)
from sonarmap.pipeline.experiments.sweep import (
    stage_path,
)

__all__ = ["COLOURS", "MAX_POINTS_PER_BOX", "box_stats", "error_rows", "plot_fig4", "pooled_errors"]


MAX_POINTS_PER_BOX = 2_000_000
"""Fig. 4 pools every trial's points per box; above this many, every k-th point is kept."""


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
        key = (protocol_of(run), spacing_of(run.get("overrides") or {}))
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
    order = protocol_order([{"protocol": p} for p, _ in pooled], protocols)
    rows = []
    for protocol in order:
        for spacing in sorted((s for p, s in pooled if p == protocol), key=spacing_sort):
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
