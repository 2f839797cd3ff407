"""The horizontal sonar's field of view inside which `evaluate` counts surface as visible
(completeness' denominator, paper Sec. V): set in the config, else as the recording
described its sonar (`sensors.json`), else a default that the report names."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from sonarmap.schemas.sensors import SonarMount
from sonarmap.stages.evaluate.config import EvaluateConfig
from sonarmap.stages.kernels.mesh_metrics import visible_mask

__all__ = ["SonarView"]

DEFAULTS = {"max_range_m": 30.0, "min_range_m": 0.0, "fan_deg": 130.0, "aperture_deg": 20.0}
"""What a recording that does not describe its sonar is taken to have."""


@dataclass(frozen=True)
class SonarView:
    """A sonar's field of view, and where each figure came from ("config", "recording"
    or "default")."""

    max_range_m: float
    min_range_m: float
    fan_deg: float
    aperture_deg: float
    sources: tuple[tuple[str, str], ...]

    @classmethod
    def of(cls, config: EvaluateConfig, sonar: SonarMount | None) -> SonarView:
        given = {
            "max_range_m": config.max_range_m,
            "min_range_m": None,
            "fan_deg": config.fan_width_deg,
            "aperture_deg": config.aperture_deg,
        }
        recorded = {
            "max_range_m": None if sonar is None else sonar.max_range_m,
            "min_range_m": None if sonar is None else sonar.min_range_m,
            "fan_deg": None if sonar is None else sonar.fov_deg,
            "aperture_deg": None if sonar is None else sonar.vertical_aperture_deg,
        }
        values, sources = {}, []
        for name, default in DEFAULTS.items():
            for source, value in (("config", given[name]), ("recording", recorded[name])):
                if value is not None and value >= 0:
                    values[name], found = float(value), source
                    break
            else:
                values[name], found = default, "default"
            sources.append((name, found))
        return cls(**values, sources=tuple(sources))

    def visible(
        self, samples: np.ndarray, T_world_sonar: np.ndarray, scene: Any = None
    ) -> np.ndarray:
        """`visible_mask` of `samples` from the keyframes' sonar poses, in this view."""
        return visible_mask(
            samples, T_world_sonar, self.max_range_m, np.deg2rad(self.fan_deg) / 2,
            np.deg2rad(self.aperture_deg) / 2, scene, min_range_m=self.min_range_m,
        )  # fmt: skip

    def as_dict(self) -> dict[str, Any]:
        return {
            "max_range_m": self.max_range_m,
            "min_range_m": self.min_range_m,
            "fan_deg": self.fan_deg,
            "aperture_deg": self.aperture_deg,
            "source": dict(self.sources),
        }
