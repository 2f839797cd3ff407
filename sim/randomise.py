"""Sensor randomisation across training missions (issue 39, item 2).

A classifier that only ever saw one clean simulated sensor is brittle: real images are
brighter and noisier. Per training mission, `draw_sensor` draws from `SensorRandomisation`
(seeded, deterministic): per sonar, the additive noise's mean level and Weibull shape,
a gain, and small mounting tilts; per mission, a factor on each class's reflectivity
(shared by both sonars: it belongs to the objects). `randomised_config` applies a draw to
a `SimConfig`.

`image_statistics` is the yardstick the ranges are chosen by: the background median of
an 8-bit image and its speckle contrast (std / mean of the pixels at or below the 80th
percentile, i.e. the background, not the objects). The default ranges span the real
Oculus and ARIS sample recordings the tests read and the simulator's own default
(`benchmarks/sensor_stats.py` measures all three; the figures: docs/classifier.md).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from sonarmap.sim.config import Mounting, SimConfig, SonarConfig
from sonarmap.stages.kernels.lazy import lazy

np = lazy("numpy")  # loads when a scene is built or drawn, not when a config is read

__all__ = ["SensorRandomisation", "draw_sensor", "image_statistics", "randomised_config"]

Span = tuple[float, float]
_SONARS = ("horizontal", "vertical")


class SensorRandomisation(BaseModel):
    """Ranges of the per-mission sensor draw; each value is uniform in its (low, high)."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    noise_mean_level: Span = Field(
        (2.0, 128.0),
        description="mean additive noise [8-bit levels], drawn log-uniformly (as many dark"
        " sensors as bright ones per octave); 2-128 spans the simulator's default 4 and the"
        " real Oculus and ARIS backgrounds (medians 43 and 89)",
    )
    noise_shape: Span = Field(
        (0.9, 4.5),
        description="Weibull shape of the noise amplitude (2: Rayleigh); 0.9-4.5 gives"
        " background speckle contrasts of about 0.8-0.22, spanning the real 0.28 (ARIS) and"
        " 0.64 (Oculus)",
    )
    gain_db: Span = Field(
        (-6.0, 6.0), description="gain on every return [dB of intensity]: saturation / 10^(g/10)"
    )
    reflectivity_share: float = Field(
        0.3,
        ge=0.0,
        lt=1.0,
        description="each class's reflectivity times a factor uniform in 1 +- this, per mission",
    )
    tilt_deg: float = Field(
        2.0,
        ge=0.0,
        le=15.0,
        description="each sonar's roll, pitch and yaw offset, uniform in +-this",
    )

    @model_validator(mode="after")
    def _ordered(self) -> SensorRandomisation:
        for name in ("noise_mean_level", "noise_shape", "gain_db"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise ValueError(f"{name}: low {lo} above high {hi}")
        if self.noise_mean_level[0] <= 0 or self.noise_mean_level[1] > 255:
            raise ValueError("noise_mean_level: must lie in (0, 255]")
        if self.noise_shape[0] < 0.5 or self.noise_shape[1] > 10:
            raise ValueError("noise_shape: must lie in [0.5, 10] (as sonar noise_shape)")
        return self


def _r(x: float) -> float:
    # Rounded: a draw is part of a simulation's recipe (JSON), so keep it short and exact.
    return round(float(x), 4)


def draw_sensor(cfg: SensorRandomisation, seed: int) -> dict[str, Any]:
    """One mission's sensor, deterministic by `seed` (draws in a fixed order).

    Returns:
        {"reflectivity_factor": {class: f}, "horizontal"/"vertical": {"noise_mean_level",
        "noise_shape", "gain_db", "tilt_deg": (roll, pitch, yaw)}}: JSON-ready.
    """
    rng = np.random.default_rng([seed, 39])
    s = cfg.reflectivity_share
    out: dict[str, Any] = {
        "reflectivity_factor": {
            name: _r(rng.uniform(1.0 - s, 1.0 + s)) for name in sorted(SonarConfig().reflectivity)
        }
    }
    lo, hi = (math.log(v) for v in cfg.noise_mean_level)
    for sonar in _SONARS:
        out[sonar] = {
            "noise_mean_level": _r(math.exp(rng.uniform(lo, hi))),
            "noise_shape": _r(rng.uniform(*cfg.noise_shape)),
            "gain_db": _r(rng.uniform(*cfg.gain_db)),
            "tilt_deg": [_r(v) for v in rng.uniform(-cfg.tilt_deg, cfg.tilt_deg, 3)],
        }
    return out


def _sonar(base: SonarConfig, draw: Mapping[str, Any], factor: Mapping[str, float]) -> SonarConfig:
    rpy = tuple(a + b for a, b in zip(base.mounting.rpy_deg, draw["tilt_deg"], strict=True))
    return base.model_copy(
        update={
            "noise_mean_level": draw["noise_mean_level"],
            "noise_shape": draw["noise_shape"],
            "saturation_intensity": base.saturation_intensity / 10 ** (draw["gain_db"] / 10),
            "reflectivity": {k: v * factor.get(k, 1.0) for k, v in base.reflectivity.items()},
            "mounting": Mounting(translation_m=base.mounting.translation_m, rpy_deg=rpy),
        }
    )


def randomised_config(base: SimConfig, draw: Mapping[str, Any]) -> SimConfig:
    """`base` with a `draw_sensor` draw applied to both sonars (validated again)."""
    factor = draw["reflectivity_factor"]
    sonars = {s: _sonar(base.sonar(s), draw[s], factor) for s in _SONARS}
    return SimConfig.model_validate(
        {**base.model_dump(), **{s: c.model_dump() for s, c in sonars.items()}}
    )


def image_statistics(image: np.ndarray) -> tuple[float, float]:
    """(background median [8-bit levels], speckle contrast) of one sonar image.

    Contrast = std / mean of the pixels at or below the image's 80th percentile: the
    background and faint returns, leaving out the bright objects.
    """
    x = np.asarray(image, dtype=np.float64).ravel()
    low = x[x <= np.percentile(x, 80)]
    mean = float(low.mean())
    return float(np.median(x)), float(low.std() / mean) if mean > 0 else 0.0
