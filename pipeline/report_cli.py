"""Human-readable run output on the terminal (tables via rich)."""

from __future__ import annotations

from typing import Any

from pipeline.engine.runner import RunResult

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
    if summary.get("model"):
        from pipeline.training.model_cache import describe

        console.print(describe(summary["model"]))
    voxels = summary.get("voxels")
    if voxels:
        metrics = summary.get("metrics") or {}
        cov = Table(title=f"Coverage ({summary.get('voxel_size_m', 0.1)} m voxels)")
        errors = metrics.get("errors", {}) if isinstance(metrics, dict) else {}
        head = metrics.get("headline") or {} if isinstance(metrics, dict) else {}
        aligned = head.get("frame") == "aligned"
        error_cols = [head.get("label", "median error m")]
        error_cols += ["raw median error m"] if aligned else []
        for col in ("map", "voxels", "accurate voxels", "completeness", *error_cols):
            cov.add_column(col)
        whole = ((metrics.get("per_class") or {}).get("classes") or {}).get("all_structure", {})
        for name in ("standard", "semantic"):
            raw = (errors.get(name) or {}).get("median_m")
            lead = (head.get("median_m") or {}).get(name, raw)
            w = whole.get(name) or {}
            cov.add_row(
                name,
                str(voxels.get(name)),
                _fmt(w.get("accurate_voxels")),
                _fmt(w.get("completeness"), "{:.3f}"),
                _fmt(lead, "{:.3f}"),
                *([_fmt(raw, "{:.3f}")] if aligned else []),
            )
        if voxels.get("standard"):
            ratio = voxels["semantic"] / voxels["standard"]
            cov.add_row(
                "semantic/standard",
                f"{ratio:.1f}x",
                _ratio(whole, "accurate_voxels"),
                _ratio(whole, "completeness"),
                *[""] * len(error_cols),
            )
        console.print(cov)
        if whole:
            console.print(
                "accurate voxels: holding a point within"
                f" {metrics['per_class'].get('tolerance_m')} m of the true surface;"
                " completeness: of the visible structure surface (all classes but the seafloor)"
            )
        submaps = metrics.get("submaps") if isinstance(metrics, dict) else None
        if submaps:
            console.print(_submaps_table(submaps))
    if summary.get("report"):
        console.print(f"report: {summary['report']}")


def _fmt(value: Any, spec: str = "{}") -> str:
    return "-" if value is None else spec.format(value)


def _ratio(figures: dict[str, Any], key: str) -> str:
    """semantic / standard of one all-structure figure, as "4.2x" ("" when undefined)."""
    a = (figures.get("semantic") or {}).get(key)
    b = (figures.get("standard") or {}).get(key)
    return f"{a / b:.1f}x" if a is not None and b else ""


_VARIANTS = (("keyframes_only", "keyframes only"), ("with_submaps", "with submaps"))


def _submaps_table(block: dict[str, Any]) -> Any:
    """Keyframes-only vs with-submaps figures of both maps (evaluate's metrics["submaps"])."""
    from rich.table import Table

    stride = block.get("stride")
    table = Table(title=f"Dense submaps (stride {_fmt(stride)}, {block.get('frames')} frames)")
    aligned = block.get("frame") == "aligned"
    medians = ["median_error_m", *(["raw_median_error_m"] if aligned else [])]
    table.add_column("map")
    table.add_column("variant", no_wrap=True)
    for col in ("voxels", "accurate voxels", "completeness", block.get("label") or "median m"):
        table.add_column(col)
    if aligned:
        table.add_column("raw median error m")
    keys = ("voxels", "accurate_voxels", "completeness", *medians)
    for name in ("standard", "semantic"):
        for variant, words in _VARIANTS:
            fig = (block.get(variant) or {}).get(name) or {}
            specs = ("{}", "{}", "{:.3f}", *["{:.3f}"] * len(medians))
            cells = (_fmt(fig.get(k), spec) for k, spec in zip(keys, specs, strict=True))
            table.add_row(name if variant == "keyframes_only" else "", words, *cells)
        ratio = (block.get("ratio") or {}).get(name) or {}
        table.add_row("", "ratio", *(_fmt(ratio.get(k), "{:.2f}x") for k in keys))
    return table
