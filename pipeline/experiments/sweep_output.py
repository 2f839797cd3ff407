"""Writing a sweep's results: sweep.parquet, table.md, sweep.png, sweep.json."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sonarmap.pipeline.experiments.sweep import RunOutcome, group_label, sweep_tables
from sonarmap.pipeline.formats.strict_json import dumps_strict

__all__ = ["write_sweep"]


def _plot(groups: Sequence[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [group_label(g) for g in groups]
    fig, ax = plt.subplots(figsize=(max(5.0, 1.6 * len(groups)), 4.0))
    width = 0.38
    for j, (metric, name) in enumerate(
        (("voxels_standard", "standard"), ("voxels_semantic", "semantic"))
    ):
        means = [g.get(metric, {}).get("mean") or 0.0 for g in groups]
        stds = [g.get(metric, {}).get("std") or 0.0 for g in groups]
        xs = [i + (j - 0.5) * width for i in range(len(groups))]
        ax.bar(xs, means, width, yerr=stds, capsize=3, label=name)
    ax.set_xticks(range(len(groups)), labels, rotation=20, ha="right")
    ax.set_ylabel("occupied voxels (mean ± std over datasets)")
    ax.legend()
    ax.set_title("Map coverage per configuration")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_sweep(outcomes: Sequence[RunOutcome], out_dir: Path) -> dict[str, Any]:
    """Write the sweep's files into `out_dir`; returns the `sweep --json` document."""
    import pyarrow.parquet as pq

    out_dir.mkdir(parents=True, exist_ok=True)
    table, groups, markdown = sweep_tables(outcomes)
    with (out_dir / "sweep.parquet").open("wb") as f:  # (pyarrow cannot take a non-UTF-8 path)
        pq.write_table(table, f)
    (out_dir / "table.md").write_text(markdown)
    plot = out_dir / "sweep.png"
    if any(o.status == "ok" for o in outcomes):
        _plot(groups, plot)
    else:  # a results folder never shows an earlier sweep's plot beside this one's table
        plot.unlink(missing_ok=True)
    doc = {"runs": [o.to_json() for o in outcomes], "groups": groups, "out": str(out_dir)}
    (out_dir / "sweep.json").write_text(dumps_strict(doc))
    return doc
