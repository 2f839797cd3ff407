"""Paper Eq. 1 for the points that infer predicts (stays here until the geometry module
of issue 36 takes it; `stages.kernels.class_query.predicted_points` calls it)."""

from __future__ import annotations

import numpy as np

__all__ = ["spherical_points"]


def spherical_points(
    range_m: np.ndarray, bearing_rad: np.ndarray, elevation_rad: np.ndarray, conf: np.ndarray
) -> dict[str, np.ndarray]:
    """Paper Eq. 1: (R, theta, phi) -> (x, y, z) in the horizontal sonar frame."""
    c = np.cos(elevation_rad)
    return {
        "range_m": range_m,
        "bearing_rad": bearing_rad,
        "elevation_rad": elevation_rad,
        "x_m": range_m * c * np.cos(bearing_rad),
        "y_m": range_m * c * np.sin(bearing_rad),
        "z_m": range_m * np.sin(elevation_rad),
        "confidence": conf,
    }
