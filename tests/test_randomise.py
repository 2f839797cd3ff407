"""Sensor randomisation (issue 39, item 2): deterministic by seed, inside its ranges, and
its extremes span the real Oculus and ARIS images' background statistics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from sonarmap.pipeline.readers.aris import ArisSource
from sonarmap.pipeline.readers.oculus_raw import parse_ping
from sonarmap.pipeline.training.datasets import read_scene, scene_path, sim_config
from sonarmap.sim.config import SimConfig
from sonarmap.sim.dataset import simulate
from sonarmap.sim.randomise import (
    SensorRandomisation,
    draw_sensor,
    image_statistics,
    randomised_config,
)


def test_the_same_seed_draws_the_same_sensor_and_another_seed_another() -> None:
    cfg = SensorRandomisation()
    assert draw_sensor(cfg, 7) == draw_sensor(cfg, 7)
    assert draw_sensor(cfg, 7) != draw_sensor(cfg, 8)


def test_every_draw_lies_in_its_configured_range() -> None:
    cfg = SensorRandomisation(
        noise_mean_level=(5.0, 20.0), noise_shape=(1.5, 2.5), gain_db=(-1.0, 2.0),
        reflectivity_share=0.1, tilt_deg=1.0,
    )  # fmt: skip
    draws = [draw_sensor(cfg, seed) for seed in range(200)]
    for d in draws:
        assert all(0.9 <= f <= 1.1 for f in d["reflectivity_factor"].values())
        for sonar in ("horizontal", "vertical"):
            s = d[sonar]
            assert 5.0 <= s["noise_mean_level"] <= 20.0
            assert 1.5 <= s["noise_shape"] <= 2.5
            assert -1.0 <= s["gain_db"] <= 2.0
            assert all(abs(t) <= 1.0 for t in s["tilt_deg"])
    # Log-uniform: about half the draws below the geometric mean (10).
    levels = np.array([d["horizontal"]["noise_mean_level"] for d in draws])
    assert 0.4 < np.mean(levels < 10.0) < 0.6


def test_a_draw_changes_the_sonars_and_keeps_the_rest() -> None:
    base = SimConfig()
    draw = draw_sensor(SensorRandomisation(), 3)
    cfg = randomised_config(base, draw)
    h = cfg.horizontal
    assert h.noise_mean_level == draw["horizontal"]["noise_mean_level"]
    assert h.noise_shape == draw["horizontal"]["noise_shape"]
    gain = base.horizontal.saturation_intensity / h.saturation_intensity
    assert gain == pytest.approx(10 ** (draw["horizontal"]["gain_db"] / 10))
    factor = draw["reflectivity_factor"]["truss"]
    assert cfg.vertical.reflectivity["truss"] == pytest.approx(0.9 * factor)
    tilt = np.subtract(cfg.vertical.mounting.rpy_deg, base.vertical.mounting.rpy_deg)
    assert np.allclose(tilt, draw["vertical"]["tilt_deg"])
    assert cfg.mission == base.mission and cfg.navigation == base.navigation


@pytest.mark.parametrize(
    "bad",
    [
        {"noise_mean_level": (20.0, 5.0)},
        {"noise_mean_level": (0.0, 5.0)},
        {"noise_shape": (0.2, 2.0)},
        {"gain_db": (3.0, -3.0)},
        {"reflectivity_share": 1.0},
        {"tilt_deg": -1.0},
    ],
)
def test_bad_ranges_are_refused(bad: dict) -> None:
    with pytest.raises(ValidationError):
        SensorRandomisation(**bad)


def _real_statistics(shared: Path) -> dict[str, tuple[float, float]]:
    ping, _ = parse_ping((shared / "oculus" / "one_ping_8bit.raw").read_bytes())
    aris = ArisSource(shared / "aris" / "sample.aris")
    stats = np.array([image_statistics(aris.frame(k).image) for k in range(len(aris._order))])
    return {
        "oculus": image_statistics(ping.image),
        "aris": (float(np.median(stats[:, 0])), float(np.median(stats[:, 1]))),
    }


def _rendered(level: float, shape: float) -> tuple[float, float]:
    """Background statistics of a tiny-scene ping rendered with that noise (gain 0 dB)."""
    draw = draw_sensor(SensorRandomisation(), 0)
    for sonar in ("horizontal", "vertical"):
        draw[sonar].update(noise_mean_level=level, noise_shape=shape, gain_db=0.0)
    cfg = sim_config(1, 10.0, draw)
    run = simulate(read_scene(scene_path("tiny")), cfg, 0)
    return image_statistics(run.frame(0).horizontal.image)


def test_the_configured_extremes_span_the_real_sensors_statistics(shared_data: Path) -> None:
    real = _real_statistics(shared_data)
    # The figures, measured again (benchmarks/sensor_stats.py).
    assert real["oculus"] == pytest.approx((43.0, 0.64), abs=0.01)
    assert real["aris"] == pytest.approx((89.0, 0.28), abs=0.01)
    cfg = SensorRandomisation()
    (lo_level, hi_level), (lo_shape, hi_shape) = cfg.noise_mean_level, cfg.noise_shape
    dark = _rendered(lo_level, 2.0)
    spiky = _rendered(hi_level, lo_shape)
    flat = _rendered(hi_level, hi_shape)
    medians = [s[0] for s in (dark, spiky, flat)]
    for name, (median, contrast) in real.items():
        assert min(medians) < median < max(medians), name
        assert flat[1] < contrast < spiky[1], name
    # The simulator's default sensor (median 4) is inside too.
    assert dark[0] < 4.0
