"""Human-readable run output on the terminal (tables via rich)."""

from __future__ import annotations

from typing import Any

from sonarmap.pipeline.engine.run.runner import RunResult
from sonarmap.pipeline.tables import print_table

__all__ = [
    "front_end_lines",
    "front_end_of",
    "front_end_summary",
    "print_summary",
    "progress_shares_stdout",
]

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
                " completeness: of the visible structure surface (all classes but the seafloor)"
                + (", at the SLAM-aligned positions" if aligned else ""),
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


# The detection front end's calibration (`features/calibration.json`), shortened for the
# run summary: one line per sonar on the terminal, the same figures under `--json`'s
# `summary.front_end`.


def _span(values: list[Any]) -> list[float] | None:
    known = [float(v) for v in values if v is not None]
    return [min(known), max(known)] if known else None


def front_end_summary(doc: dict[str, Any]) -> dict[str, Any]:
    """Per sonar: the spans over range bands of the background median, the intensity floor
    and the threshold factor, which were measured or pinned, the expected false alarms per
    ping, and what detection measured; plus the stated rate and the warnings."""
    pinned = {k: v for k, v in (doc.get("pinned") or {}).items() if v is not None}
    sonars = {}
    for sonar, entry in sorted((doc.get("sonars") or {}).items()):
        bands = entry.get("bands") or []
        measured = entry.get("measured") or {}
        sonars[sonar] = {
            "bands": len(bands),
            "background_bands": sum(bool(b.get("background")) for b in bands),
            "sampled_pings": len(entry.get("sampled_t_ns") or []),
            "denoise": entry.get("denoise", "none"),
            "background_median_levels": _span([b.get("median_level") for b in bands]),
            "intensity_floor_levels": _span([b.get("intensity_floor_levels") for b in bands]),
            "threshold_factor": _span([b.get("threshold_factor") for b in bands]),
            "expected_false_alarms_per_ping": entry.get("expected_false_alarms_per_ping"),
            "background_detection_rate": measured.get("background_detection_rate"),
            "features_per_keyframe": measured.get("features_per_keyframe"),
            "keyframes_clipped": measured.get("keyframes_clipped"),
            "features_dropped": measured.get("features_dropped"),
        }
    return {
        "stated_false_alarm_rate_per_cell": doc.get("stated_false_alarm_rate_per_cell"),
        "measured": doc.get("measured"),
        "pinned": pinned,
        "sonars": sonars,
        "warnings": list(doc.get("warnings") or []),
    }


def _fmt_span(span: list[float] | None, spec: str = "{:g}") -> str:
    if not span:
        return "-"
    lo, hi = (spec.format(v) for v in span)
    return lo if lo == hi else f"{lo}-{hi}"


def front_end_lines(summary: dict[str, Any]) -> list[str]:
    """One line per sonar (empty without a calibration)."""
    block = summary.get("front_end") or {}
    pinned = block.get("pinned") or {}
    whole = "bands" in pinned  # features.pinned_bands: every band's thresholds
    how = {
        "floor": "pinned" if whole or "intensity_floor" in pinned else "measured",
        "tau": "pinned" if whole or "threshold_factor" in pinned else "measured",
    }
    lines = []
    for sonar, s in (block.get("sonars") or {}).items():
        measured = s["background_detection_rate"]
        lines.append(
            f"front end, {sonar}: background median"
            f" {_fmt_span(s['background_median_levels'], '{:.0f}')} levels over {s['bands']}"
            f" range bands ({s['background_bands']} background);"
            f"{_filter(s.get('denoise'))}"
            f" floor {_fmt_span(s['intensity_floor_levels'], '{:.0f}')} ({how['floor']}),"
            f" CFAR factor {_fmt_span(s['threshold_factor'], '{:.2f}')} ({how['tau']});"
            f" false alarms stated {_rate(block.get('stated_false_alarm_rate_per_cell'))}/cell,"
            f" measured on background {_rate(measured)};"
            f" {_count(s['features_per_keyframe'])} features/keyframe"
            f"{_expected(s['expected_false_alarms_per_ping'])},"
            f" {s['keyframes_clipped']} keyframes clipped by the budget"
        )
    return lines


def _expected(per_ping: float | None) -> str:
    """The false alarms the calibration expects per ping; none for pinned thresholds,
    whose run measured no rate for them."""
    return "" if per_ping is None else f" ({_count(per_ping)} false alarms expected per ping)"


def _filter(denoise: str | None) -> str:
    """The filter the calibration chose, as the line says it ("" for none)."""
    if not denoise or denoise == "none":
        return ""
    # Read off the name, not `front_end.FILTER_SIZE`: a fully cached run prints this line
    # and must not load numpy (tests/test_demo.py).
    size = {"beam3": "1x3", "range3": "3x1"}.get(denoise, denoise.removeprefix("box"))
    return f" {size} mean filter (range x beam);"


def _rate(value: float | None) -> str:
    return "-" if value is None else f"{value:.1e}"


def _count(value: float | None) -> str:
    return "-" if value is None else f"{value:,.0f}"


def front_end_of(result: RunResult) -> dict[str, Any]:
    """{"front_end": the features stage's calibration, shortened per sonar} ({} without)."""
    import json
    from pathlib import Path

    ref = result.artifacts.get("features")
    path = None if ref is None else Path(ref.path) / "calibration.json"
    if path is None or not path.is_file():
        return {}
    return {"front_end": front_end_summary(json.loads(path.read_text()))}
