"""Human-readable run output on the terminal (tables via rich)."""

from __future__ import annotations

from typing import Any

from sonarmap.pipeline.engine.run.runner import RunResult
from sonarmap.pipeline.tables import print_table

__all__ = ["print_summary", "progress_shares_stdout"]

KEY_CHARS = 12
"""Characters of an artifact key shown on the terminal (`--json` gives the whole path)."""


def progress_shares_stdout() -> bool:
    """Whether stderr (where the progress lists each stage) is the very file, pipe or
    terminal stdout is: a log written with `2>&1`, or a terminal."""
    import os

    try:
        out, err = os.fstat(1), os.fstat(2)
    except OSError:
        return False
    return (out.st_dev, out.st_ino) == (err.st_dev, err.st_ino)


def print_summary(
    result: RunResult, summary: dict[str, Any], *, stages_listed: bool = False
) -> None:
    """Stage table (unless `stages_listed`: the progress already printed each stage to
    the same output), then the coverage table when the map stages ran.

    Tables print whole or as plain lines (`sonarmap.pipeline.tables.print_table`):
    no header or value is ever cut, at 80 columns or in a log file. Artifacts are named by
    their stage and a short key (`STORE/STAGE/KEY...`; `--json` gives whole paths).
    """
    from rich.console import Console

    console = Console()
    _line(console, f"sonarmap run: {result.dataset}")
    _line(console, f"artifacts: {result.store}/STAGE/KEY")
    if not stages_listed:
        print_table(
            console,
            "",
            ("stage", "status", "seconds", "key"),
            [(r.stage, r.status, f"{r.seconds:.2f}", r.key[:KEY_CHARS]) for r in result.stages],
        )
    if summary.get("model"):
        from sonarmap.pipeline.training.model_cache import describe

        _line(console, describe(summary["model"]))
    voxels = summary.get("voxels")
    if voxels:
        metrics = summary.get("metrics") or {}
        errors = metrics.get("errors", {}) if isinstance(metrics, dict) else {}
        head = metrics.get("headline") or {} if isinstance(metrics, dict) else {}
        aligned = head.get("frame") == "aligned"
        error_cols = [head.get("label", "median error m")]
        error_cols += ["raw median error m"] if aligned else []
        whole = ((metrics.get("per_class") or {}).get("classes") or {}).get("all_structure", {})
        rows: list[tuple[str, ...]] = []
        for name in ("standard", "semantic"):
            raw = (errors.get(name) or {}).get("median_m")
            lead = (head.get("median_m") or {}).get(name, raw)
            w = whole.get(name) or {}
            rows.append(
                (
                    name,
                    str(voxels.get(name)),
                    _fmt(w.get("accurate_voxels")),
                    _fmt(w.get("completeness"), "{:.3f}"),
                    _fmt(lead, "{:.3f}"),
                    *([_fmt(raw, "{:.3f}")] if aligned else []),
                )
            )
        if voxels.get("standard"):
            ratio = voxels["semantic"] / voxels["standard"]
            rows.append(
                (
                    "semantic/standard",
                    f"{ratio:.1f}x",
                    _ratio(whole, "accurate_voxels"),
                    _ratio(whole, "completeness"),
                    *[""] * len(error_cols),
                )
            )
        print_table(
            console,
            f"Coverage ({summary.get('voxel_size_m', 0.1)} m voxels)",
            ("map", "voxels", "accurate voxels", "completeness", *error_cols),
            rows,
        )
        if whole:
            _line(
                console,
                "accurate voxels: holding a point within"
                f" {metrics['per_class'].get('tolerance_m')} m of the true surface;"
                " completeness: of the visible structure surface (all classes but the seafloor)",
            )
        submaps = metrics.get("submaps") if isinstance(metrics, dict) else None
        if submaps:
            _submaps_table(console, submaps)
    if summary.get("report"):
        _line(console, f"report: {summary['report']}")


def _line(console: Any, text: str) -> None:
    """One line of text, never re-wrapped by rich (a path stays whole and copyable)."""
    console.print(text, soft_wrap=True, markup=False, highlight=False)


def _fmt(value: Any, spec: str = "{}") -> str:
    return "-" if value is None else spec.format(value)


def _ratio(figures: dict[str, Any], key: str) -> str:
    """semantic / standard of one all-structure figure, as "4.2x" ("" when undefined)."""
    a = (figures.get("semantic") or {}).get(key)
    b = (figures.get("standard") or {}).get(key)
    return f"{a / b:.1f}x" if a is not None and b else ""


_VARIANTS = (("keyframes_only", "keyframes only"), ("with_submaps", "with submaps"))


def _submaps_table(console: Any, block: dict[str, Any]) -> None:
    """Keyframes-only vs with-submaps figures of both maps (evaluate's metrics["submaps"])."""
    stride = block.get("stride")
    title = f"Dense submaps (stride {_fmt(stride)}, {block.get('frames')} frames)"
    aligned = block.get("frame") == "aligned"
    medians = ["median_error_m", *(["raw_median_error_m"] if aligned else [])]
    columns = ["map", "voxels", "accurate voxels", "completeness"]
    columns.append(block.get("label") or "median m")
    if aligned:
        columns.append("raw median error m")
    keys = ("voxels", "accurate_voxels", "completeness", *medians)
    rows: list[tuple[str, ...]] = []
    for name in ("standard", "semantic"):
        for variant, words in _VARIANTS:
            fig = (block.get(variant) or {}).get(name) or {}
            specs = ("{}", "{}", "{:.3f}", *["{:.3f}"] * len(medians))
            cells = (_fmt(fig.get(k), spec) for k, spec in zip(keys, specs, strict=True))
            rows.append((f"{name}, {words}", *cells))
        ratio = (block.get("ratio") or {}).get(name) or {}
        rows.append((f"{name}, ratio", *(_fmt(ratio.get(k), "{:.2f}x") for k in keys)))
    print_table(console, title, columns, rows)
