"""Each sonar's geometry as `sensors.json` records it, the one place every stage takes the
fan from (`slam.nssm_aperture_deg`, `evaluate.fan_width_deg` default to it)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from sonarmap.schemas.sonar import SonarPing

__all__ = ["sonar_geometry"]


def sonar_geometry(ping: SonarPing, described: Mapping[str, Any] | None) -> dict[str, Any]:
    """Fan, range window, vertical aperture and beam-table summary of one sonar.

    Args:
        ping: a decoded ping of the sonar (its beam angles and range bins).
        described: what the reader knows beyond the messages (preset or table file: fan,
            vertical aperture, datasheet; polar images: the configured fan), or None.

    Returns:
        JSON-able {"fov_deg", "max_range_m", "min_range_m", "vertical_aperture_deg",
        "beams": {count, first/last angle, min/max spacing [deg]}, "geometry": where the
        beam table and figures come from}.
    """
    angles = np.sort(np.rad2deg(ping.angles_rad.astype(np.float64)))
    known = dict(described or {})
    n = len(angles)
    # A table of beam centres spans n - 1 spacings; the fan covers n (half a beam each side).
    span = float(angles[-1] - angles[0]) * n / (n - 1) if n > 1 else 0.0
    fov = known.pop("fov_deg", None)
    step = np.diff(angles)
    half_bin = ping.range_resolution_m / 2
    return {
        "fov_deg": round(float(fov) if fov is not None else span, 3),
        "max_range_m": round(float(ping.ranges_m[-1]) + half_bin, 3),
        "min_range_m": round(max(float(ping.ranges_m[0]) - half_bin, 0.0), 3),
        "vertical_aperture_deg": known.pop("vertical_aperture_deg", None),
        "beams": {
            "count": n,
            "first_deg": round(float(angles[0]), 4),
            "last_deg": round(float(angles[-1]), 4),
            "min_spacing_deg": round(float(step.min()), 4) if n > 1 else 0.0,
            "max_spacing_deg": round(float(step.max()), 4) if n > 1 else 0.0,
        },
        "geometry": known or {"beam_table": "message"},
    }
