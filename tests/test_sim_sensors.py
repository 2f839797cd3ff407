"""Simulated sensors (issue 50, item 1): the presets' image blocks are the real files'
statistics, the simulator reproduces them within 20 %, `simulate --sonar/--set` take
them, and the clean sensor keeps its bytes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.readers.sonar_models import PRESETS_DIR, preset_names
from sonarmap.pipeline.training.datasets import Simulation, read_scene, scene_path, sim_config
from sonarmap.pipeline.training.sim_sensors import (
    CLEAN,
    OCULUS_PAIR,
    image_block,
    sensor_names,
    sensor_settings,
    with_sensors,
    with_settings,
)
from sonarmap.sim.config import SimConfig
from sonarmap.sim.dataset import simulate
from sonarmap.sim.image_stats import image_character

TINY = Path(__file__).resolve().parents[1] / "configs" / "scenes" / "tiny.yaml"
CHECKED = ("background_median", "speckle_contrast", "lag1_range", "lag1_beam")
_SIMULATED: dict[tuple, dict] = {}


def _simulated(name: str) -> dict:
    """Image character of 4 horizontal and 4 vertical marina pings under sensor `name`
    (one short simulation per distinct set of settings)."""
    key = tuple(sorted(sensor_settings(name).items()))
    if key not in _SIMULATED:
        cfg = sim_config(2, 12.0, sonars={"horizontal": name, "vertical": name})
        run = simulate(read_scene(scene_path("marina")), cfg, 0)
        idx = np.linspace(0, run.n_frames - 1, 4).round().astype(int)
        frames = [run.frame(int(i)) for i in idx]
        _SIMULATED[key] = {
            s: image_character([getattr(f, s).image for f in frames])
            for s in ("horizontal", "vertical")
        }
    return _SIMULATED[key]


@pytest.mark.parametrize("name", [n for n in sensor_names() if n != CLEAN])
def test_each_preset_reproduces_its_stated_statistics_within_20_percent(name: str) -> None:
    block = image_block(name)
    stated = block["statistics"]
    for sonar, got in _simulated(name).items():
        keys = list(CHECKED)
        if block["simulator"].get("noise_range_slope_db"):
            keys.append("range_slope_db")  # a sensor's range profile (the Oculus': the scene's)
        for key in keys:
            assert got[key] == pytest.approx(stated[key], rel=0.2), (name, sonar, key, got)


def test_every_preset_states_its_image_character_and_whether_it_was_measured() -> None:
    assert set(sensor_names()) == {CLEAN, *preset_names()}
    measured = {n for n in preset_names() if image_block(n)["source"] == "measured"}
    assert measured == {"oculus-m1200d-2100khz", "aris1800-48"}
    for name in set(preset_names()) - measured:
        assert image_block(name)["provenance"].startswith("no real file of this sonar")
        assert "assumed" in (PRESETS_DIR / f"{name}.yaml").read_text()


def test_the_real_files_statistics_are_the_presets(shared_data: Path) -> None:
    from benchmarks.sensor_stats import aris_images, oculus_images

    real = {
        "oculus-m1200d-2100khz": oculus_images(shared_data / "oculus" / "one_ping_8bit.raw"),
        "aris1800-48": aris_images(shared_data / "aris" / "sample.aris"),
    }
    for name, images in real.items():
        stated, got = image_block(name)["statistics"], image_character(images)
        for key in (*CHECKED, "range_slope_db", "images"):
            assert got[key] == pytest.approx(stated[key], abs=0.002 if key in CHECKED[1:] else 0.1)
        assert got["band_medians"] == pytest.approx(stated["band_medians"], abs=0.1)


def test_the_clean_sensor_is_the_library_default_and_keeps_its_bytes() -> None:
    both_clean = {"horizontal": CLEAN, "vertical": CLEAN}
    assert sim_config(2, 1.0, sonars=both_clean) == sim_config(2, 1.0)
    assert with_sensors(SimConfig(), both_clean) == SimConfig()
    cfg = SimConfig()
    assert not cfg.horizontal.textured and not cfg.vertical.textured
    # What a recording carries of a clean config: the keys it had before the new knobs.
    dumped = json.loads(cfg.model_dump_json(exclude=cfg.unrecorded()))  # type: ignore[arg-type]
    assert not {"gain_db", "noise_corr_range", "noise_corr_beam"} & set(dumped["horizontal"])
    oculus = with_sensors(cfg, OCULUS_PAIR)
    assert (
        "noise_corr_beam"
        in json.loads(oculus.model_dump_json(exclude=oculus.unrecorded()))["vertical"]
    )


def test_a_textured_sensor_is_deterministic_per_seed() -> None:
    from sonarmap.sim.scene import load_scene

    cfg = with_sensors(sim_config(1, 1.0), {"horizontal": "oculus-m750d-750khz"})
    a, b, c = (simulate(load_scene(TINY), cfg, seed).frame(1) for seed in (5, 5, 6))
    assert np.array_equal(a.horizontal.image, b.horizontal.image)
    assert not np.array_equal(a.horizontal.image, c.horizontal.image)


def test_a_recording_recipe_names_its_sensors_and_the_clean_default_stays_as_it_was() -> None:
    marina = scene_path("marina")
    clean = Simulation(marina, 0, Path("x.mcap"), 2)
    oculus = Simulation(marina, 0, Path("x.mcap"), 2, sonars=OCULUS_PAIR)
    assert "sonars" not in clean.recipe()
    recipe = oculus.recipe()["sonars"]
    assert recipe["horizontal"]["name"] == "oculus-m750d-750khz"
    assert recipe["vertical"] == {"name": "oculus-m1200d", **sensor_settings("oculus-m1200d")}


def test_settings_apply_and_bad_ones_are_one_line() -> None:
    cfg = with_settings(SimConfig(), ["horizontal.noise_mean_level=53", "mission.n_goals=3"])
    assert cfg.horizontal.noise_mean_level == 53.0 and cfg.mission.n_goals == 3
    for bad, text in (
        ("horizontal.noise_level=3", "unknown key 'noise_level' in horizontal"),
        ("noise_mean_level=3", "unknown key 'noise_mean_level'"),
        ("horizontal.noise_corr_beam=1.5", "noise_corr_beam"),
        ("horizontal", "expected KEY=VALUE"),
    ):
        with pytest.raises(ConfigError, match=text):
            with_settings(SimConfig(), [bad])
    with pytest.raises(ConfigError, match="no simulated sensor of that name"):
        with_sensors(SimConfig(), {"vertical": "oculus-m9000"})


def test_cli_simulate_takes_sensors_and_settings(tmp_path: Path) -> None:
    from mcap.reader import make_reader

    from sonarmap.pipeline.cli import app

    out = tmp_path / "x.mcap"
    args = ["simulate", "-o", str(out), "--scene", str(TINY), "--goals", "1", "-q"]
    sensors = ["--sonar", "aris1800-48", "--vertical-sonar", "oculus-m1200d"]
    result = CliRunner().invoke(
        app, [*args, "--duration-s", "1", *sensors, "--set", "horizontal.noise_mean_level=70"]
    )
    assert result.exit_code == 0, result.output
    assert "horizontal aris1800-48, vertical oculus-m1200d" in result.output
    with out.open("rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}["sonarmap"]
    cfg = json.loads(meta["config"])
    assert cfg["horizontal"]["noise_mean_level"] == 70.0
    assert cfg["horizontal"]["noise_range_slope_db"] == -8.8
    assert cfg["vertical"]["noise_corr_beam"] == sensor_settings("oculus-m1200d")["noise_corr_beam"]
    for bad in (["--sonar", "nope"], ["--horizontal-sonar", "nope"], ["--set", "x.y=1"]):
        r = CliRunner().invoke(app, [*args, *bad])
        assert r.exit_code == 2, r.output
        assert r.output.count("\n") == 1 and "error:" in r.output
