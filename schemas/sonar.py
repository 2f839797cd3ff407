"""Value types for sonar pings and keyframes, and the beam-direction convention.

Conventions (docs/architecture.md#conventions): ROS REP 103 frames (x forward, y left, z up), angles in
radians. A polar image has rows = range bins (near to far) and columns = beams,
with an explicit per-beam angle table sorted ascending.

Horizontal sonar: `angles_rad` are bearings theta (positive left).
Vertical sonar: the same head rolled +90 deg about its forward axis, so the
sensor's left becomes up; its `angles_rad` are elevations phi (positive up).

`marine_acoustic_msgs/ProjectedSonarImage` frame: Z forward in the fan plane,
X up, Y = Z x X = right. A beam at fan angle a (positive to the sensor's left)
therefore has direction (0, -sin a, cos a).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "KeyframeImages",
    "SonarPing",
    "beam_angles_from_directions",
    "beam_directions_from_angles",
]


def beam_directions_from_angles(angles_rad: np.ndarray) -> np.ndarray:
    """Unit beam vectors in the ProjectedSonarImage frame.

    Args:
        angles_rad: (n,) fan angle of each beam, positive to the sensor's left.

    Returns:
        (n, 3) float64 unit vectors (x up, y right, z forward).
    """
    a = np.asarray(angles_rad, dtype=np.float64)
    return np.stack([np.zeros_like(a), -np.sin(a), np.cos(a)], axis=1)


def beam_angles_from_directions(directions: np.ndarray) -> np.ndarray:
    """Inverse of `beam_directions_from_angles`: (n, 3) vectors -> (n,) angles [rad]."""
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    return np.arctan2(-d[:, 1], d[:, 2])


@dataclass(frozen=True)
class SonarPing:
    """One decoded polar sonar image.

    Attributes:
        t_ns: ping time [ns].
        sonar: "horizontal" or "vertical".
        image: (n_ranges, n_beams) uint8 intensities.
        ranges_m: (n_ranges,) float32 bin-centre ranges, ascending.
        angles_rad: (n_beams,) float32 beam angles, ascending (bearing or elevation).
        labels: optional (n_ranges, n_beams) uint8 ground-truth class ids (0 = none).
        truth_angle_rad: optional (n_ranges, n_beams) float32 true elevation
            (horizontal sonar) or bearing (vertical sonar) of the strongest hit, NaN = none.
        frequency_hz, sound_speed_m_s: the ping's, as the recording states them (0: not
            stated; a ProjectedSonarImage's `ping_info` writes them through).
    """

    t_ns: int
    sonar: str
    image: np.ndarray
    ranges_m: np.ndarray
    angles_rad: np.ndarray
    labels: np.ndarray | None = None
    truth_angle_rad: np.ndarray | None = None
    frequency_hz: float = 0.0
    sound_speed_m_s: float = 0.0

    @property
    def range_resolution_m(self) -> float:
        """Mean bin spacing [m] (bins need not start at 0)."""
        r = self.ranges_m
        return float((r[-1] - r[0]) / max(len(r) - 1, 1))


@dataclass(frozen=True)
class KeyframeImages:
    """Both sonar images of one keyframe (what `keyframes.mcap` stores per keyframe)."""

    keyframe_id: int
    t_ns: int
    horizontal: SonarPing
    vertical: SonarPing
    extras: dict[str, float] = field(default_factory=dict)
