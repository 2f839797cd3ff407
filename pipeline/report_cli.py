"""Human-readable run output on the terminal (tables via rich)."""

from __future__ import annotations

from typing import Any

from pipeline.runner import RunResult

__all__ = ["print_summary"]


def print_summary(result: RunResult, summary: dict[str, Any]) -> None:
    """Stage table, then the coverage table when the map stages ran."""
    from rich.console import Console
    from rich.table import Table

    console = Console()
    table = Table(title=f"sonarmap run: {result.dataset}")
    for col in ("stage", "status", "seconds", "artifact"):
        table.add_column(col)
    for r in result.stages:
        table.add_row(r.stage, r.status, f"{r.seconds:.2f}", r.path)
    console.print(table)
    voxels = summary.get("voxels")
    if voxels:
        metrics = summary.get("metrics") or {}
        cov = Table(title=f"Coverage ({summary.get('voxel_size_m', 0.1)} m voxels)")
        for col in ("map", "voxels", "median error m"):
            cov.add_column(col)
        errors = metrics.get("errors", {}) if isinstance(metrics, dict) else {}
        for name in ("standard", "semantic"):
            med = (errors.get(name) or {}).get("median_m")
            cov.add_row(name, str(voxels.get(name)), "-" if med is None else f"{med:.3f}")
        if voxels.get("standard"):
            ratio = voxels["semantic"] / voxels["standard"]
            cov.add_row("semantic/standard", f"{ratio:.1f}x", "")
        console.print(cov)
    if summary.get("report"):
        console.print(f"report: {summary['report']}")
