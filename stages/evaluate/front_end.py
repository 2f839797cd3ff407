"""The report's front-end section: what the features stage's calibration measured and set,
how much of what it detected became map evidence, and its flood / starve warnings
(`sonarmap.stages.features.calibration` states the warning rules)."""

from __future__ import annotations

from typing import Any

__all__ = ["front_end_markdown", "front_end_report"]


def front_end_report(
    calibration: dict[str, Any] | None, fused_points: int, objects: int, keyframes: int
) -> dict[str, Any] | None:
    """The figures of the report's section (None without a calibration)."""
    if not calibration:
        return None
    sonars = {}
    features = 0.0
    for sonar, entry in sorted((calibration.get("sonars") or {}).items()):
        measured = entry.get("measured") or {}
        per_kf = float(measured.get("features_per_keyframe") or 0.0)
        features += per_kf * keyframes
        sonars[sonar] = {
            "background_bands": measured.get("background_bands"),
            "background_detection_rate": measured.get("background_detection_rate"),
            "expected_false_alarms_per_ping": entry.get("expected_false_alarms_per_ping"),
            "features_per_keyframe": per_kf,
            "keyframes_clipped": measured.get("keyframes_clipped"),
            "features_dropped": measured.get("features_dropped"),
        }
    horizontal = sonars.get("horizontal", {}).get("features_per_keyframe", 0.0) * keyframes
    return {
        "stated_false_alarm_rate_per_cell": calibration.get("stated_false_alarm_rate_per_cell"),
        "measured": calibration.get("measured"),
        "pinned": {k: v for k, v in (calibration.get("pinned") or {}).items() if v is not None},
        "sonars": sonars,
        "fused_share_of_horizontal_features": round(fused_points / horizontal, 4)
        if horizontal
        else None,
        "objects_per_keyframe": round(objects / keyframes, 2) if keyframes else None,
        "warnings": list(calibration.get("warnings") or []),
    }


def front_end_markdown(block: dict[str, Any] | None) -> list[str]:
    """The report's "Front end" section."""
    if not block:
        return []
    pinned = block.get("pinned") or {}
    how = "pinned by the config" if "bands" in pinned else "calibrated from the recording"
    lines = [
        f"## Front end (detection thresholds {how})",
        "",
        f"Stated false-alarm rate: {block['stated_false_alarm_rate_per_cell']} per cell;"
        f" measured from the recording: {', '.join(block.get('measured') or []) or 'nothing'};"
        f" pinned by the config: {_pins(pinned)}.",
        "",
        "| sonar | features / keyframe | expected false alarms / ping | background bands"
        " | detection rate on background | keyframes clipped | features dropped |",
        "|---|---:|---:|---|---:|---:|---:|",
    ]
    for sonar, s in block["sonars"].items():
        cells = [s[k] for k in ("features_per_keyframe", "expected_false_alarms_per_ping",
                                "background_bands", "background_detection_rate",
                                "keyframes_clipped", "features_dropped")]  # fmt: skip
        lines.append(
            f"| {sonar} | " + " | ".join("-" if c is None else str(c) for c in cells) + " |"
        )
    lines += [
        "",
        f"- fused points per horizontal feature: {block['fused_share_of_horizontal_features']}",
        f"- objects per keyframe: {block['objects_per_keyframe']}",
    ]
    lines += [f"- **warning:** {w}" for w in block.get("warnings") or []]
    return [*lines, ""]


def _pins(pinned: dict[str, Any]) -> str:
    """`name (where), ...` of what the config pinned: every band's thresholds (a whole
    calibration) or single settings with their values."""
    if not pinned:
        return "nothing"
    if "bands" in pinned:
        return f"every band's floor, CFAR factor and filter ({pinned['bands']})"
    return ", ".join(f"{name} {value}" for name, value in sorted(pinned.items()))
