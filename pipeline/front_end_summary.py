"""The detection front end's calibration (`features/calibration.json`), shortened for the
run summary: one line per sonar on the terminal, the same figures under `--json`'s
`summary.front_end`."""

from __future__ import annotations

from typing import Any

__all__ = ["front_end_lines", "front_end_summary"]


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
            "sampled_pings": len(entry.get("sampled_keyframes") or []),
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
    how = {
        "floor": "pinned" if "intensity_floor" in pinned else "measured",
        "tau": "pinned" if "threshold_factor" in pinned else "measured",
    }
    lines = []
    for sonar, s in (block.get("sonars") or {}).items():
        lines.append(
            f"front end, {sonar}: background median {_fmt_span(s['background_median_levels'])}"
            f" levels over {s['bands']} range bands ({s['background_bands']} background);"
            f" floor {_fmt_span(s['intensity_floor_levels'])} ({how['floor']}),"
            f" CFAR factor {_fmt_span(s['threshold_factor'], '{:.2f}')} ({how['tau']});"
            f" stated false alarms {block.get('stated_false_alarm_rate_per_cell')}/cell,"
            f" measured on background {s['background_detection_rate']};"
            f" {s['features_per_keyframe']} features/keyframe"
            f" (expected false alarms {s['expected_false_alarms_per_ping']}/ping),"
            f" {s['keyframes_clipped']} keyframes clipped by the budget"
        )
    return lines
