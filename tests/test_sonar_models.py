"""Sonar geometry per sonar: presets citing datasheets, beam-table files, uneven polar
images, and the fan every stage takes from the keyframes sensors."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from test_readers_mcap import N_BEAMS, N_RANGES, T0, odom_msg

from sonarmap.pipeline.engine.errors import ConfigError, SourceError
from sonarmap.pipeline.formats.rosmsg import Ros2McapWriter, ros2_typestore
from sonarmap.pipeline.readers import open_recording
from sonarmap.pipeline.readers.sonar_models import fov_of_table, load_sonar, preset_names
from sonarmap.schemas.topics import ODOMETRY_TYPE, TOPIC_DEAD_RECKONING
from sonarmap.stages.keyframes import STAGE, KeyframesConfig
from sonarmap.stages.slam.config import SlamConfig, with_sensor_fan

REQUIRED = {
    "oculus-m750d-750khz": 130.0,
    "oculus-m750d-1200khz": 70.0,
    "oculus-m1200d": 130.0,
    "blueview-p900-130": 130.0,
    "aris3000-64": None,
    "aris3000-128": None,
    "aris1800-48": None,
    "aris1800-96": None,
    "gemini-720i": 130.0,
}
H_TOPIC, V_TOPIC = "/m750d/image", "/m1200d/image"


def test_every_preset_cites_its_datasheet() -> None:
    assert set(REQUIRED) <= set(preset_names())
    for name in preset_names():
        model = load_sonar(name)
        assert model.name == name and model.source == f"preset {name}"
        assert model.datasheet["title"] and model.datasheet["url"].startswith("http")
        assert model.max_range_m and model.vertical_aperture_deg
        if REQUIRED.get(name) is not None:
            assert model.fov_deg == REQUIRED[name]


@pytest.mark.parametrize(
    ("preset", "header"),
    [
        ("aris1800-48", "BeamWidths_ARIS1800_1200_48.h"),
        ("aris1800-96", "BeamWidths_ARIS1800_96.h"),
        ("aris3000-64", "BeamWidths_ARIS3000_64.h"),
        ("aris3000-128", "BeamWidths_ARIS3000_128.h"),
    ],
)
def test_aris_presets_are_the_makers_tables(shared_data: Path, preset: str, header: str) -> None:
    rows = re.findall(
        r"DEFINE_BEAMWIDTH3\((\d+),\s*([-\d.]+),\s*([-\d.]+),\s*([-\d.]+)\)",
        (shared_data / "aris" / header).read_text(),
    )
    table = np.array([[float(v) for v in r[1:]] for r in rows])
    model = load_sonar(preset)
    assert model.beam_angles_deg is not None
    np.testing.assert_array_equal(model.beam_angles_deg, table[:, 0])
    # The fan is the outer beam edges: left edge of beam 0 to right edge of the last.
    assert model.fov_deg == pytest.approx(table[-1, 2] - table[0, 1], abs=1e-4)


def test_table_files_and_their_refusals(tmp_path: Path) -> None:
    csv = tmp_path / "m750d.csv"
    csv.write_text("# measured\nangle_deg\n-60, -20.5\n0.0 20.5\n60\n")
    model = load_sonar(str(csv))
    np.testing.assert_array_equal(model.beam_angles_deg, [-60, -20.5, 0, 20.5, 60])
    assert model.fov_deg == pytest.approx(120 * 5 / 4)
    yml = tmp_path / "sonar.yaml"
    yml.write_text("fov_deg: 90\nvertical_aperture_deg: 12\nbeam_angles_deg: [40, 10, -10, -40]\n")
    assert load_sonar(str(yml)).fov_deg == 90.0
    assert load_sonar(str(yml)).vertical_aperture_deg == 12.0
    cases = {
        "3\n1\n2\n": "strictly monotonic",
        "1\nnan\n": "'nan' is not a number",
        "1\n2\nabc\n": r":3: 'abc' is not a number",
        "5\n": "2 to 4096 angles",
        "1\n200\n": "within \\[-180, 180\\]",
    }
    for k, (text, message) in enumerate(cases.items()):
        bad = tmp_path / f"bad{k}.csv"
        bad.write_text(text)
        with pytest.raises(ConfigError, match=re.escape(str(bad)) + ".*" + message):
            load_sonar(str(bad))
    with pytest.raises(
        ConfigError, match=r"'m750' : neither a preset|neither a preset \(.*gemini-720i"
    ):
        load_sonar("m750")


def _polar_recording(path: Path, images: list[np.ndarray], labels: bool = False) -> None:
    t = ros2_typestore().types
    with path.open("wb") as f, Ros2McapWriter(f) as w:
        for k, image in enumerate(images):
            tk = T0 + k * 500_000_000
            stamp = t["builtin_interfaces/msg/Time"](sec=tk // 10**9, nanosec=tk % 10**9)
            for topic in (H_TOPIC, V_TOPIC):
                msg = t["sensor_msgs/msg/Image"](
                    header=t["std_msgs/msg/Header"](stamp=stamp, frame_id=topic),
                    height=N_RANGES,
                    width=N_BEAMS,
                    encoding="mono8",
                    is_bigendian=0,
                    step=N_BEAMS,
                    data=image.reshape(-1),
                )
                w.write(topic, "sensor_msgs/msg/Image", msg, tk)
                if labels:  # a label image equal to the sonar image, column for column
                    w.write(f"{topic}/labels", "sensor_msgs/msg/Image", msg, tk)
            w.write(TOPIC_DEAD_RECKONING, ODOMETRY_TYPE, odom_msg(tk, 1.0 * k, 0.0, -2.0, 0.0), tk)


def test_polar_images_use_each_sonars_own_uneven_table(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    images = [rng.integers(0, 255, (N_RANGES, N_BEAMS), dtype=np.uint8) for _ in range(6)]
    path = tmp_path / "polar.mcap"
    _polar_recording(path, images)
    # An M750d-like table: column 0 at port (+65 deg), spacing widening toward the edges.
    u = np.linspace(1.0, -1.0, N_BEAMS)
    table = 65.0 * np.sin(u * np.pi / 2) ** 1 * (0.6 + 0.4 * np.abs(u))
    csv = tmp_path / "m750d_beams.csv"
    csv.write_text("\n".join(f"{a:.6f}" for a in table) + "\n")
    cfg = KeyframesConfig(
        horizontal_topic=H_TOPIC,
        vertical_topic=V_TOPIC,
        horizontal_sonar=str(csv),
        vertical_sonar="oculus-m1200d",
        vertical_image_max_range_m=5.0,
    )
    rec = open_recording(path, cfg)
    h, v = next(rec.pings("horizontal", [2])), next(rec.pings("vertical", [2]))
    # Angles ascend, so the table's column 0 (+65 deg) is the last column.
    np.testing.assert_allclose(np.rad2deg(h.angles_rad), table[::-1], atol=1e-4)
    np.testing.assert_array_equal(h.image, images[2][:, ::-1])
    spacing = np.diff(np.rad2deg(h.angles_rad))
    assert spacing.max() / spacing.min() > 1.5  # uneven, as given
    np.testing.assert_allclose(h.ranges_m[[0, -1]], [0.375, 29.625], atol=1e-5)  # 30 m default
    # The preset has no table: even spacing over its 130 deg; its own range window.
    np.testing.assert_allclose(np.rad2deg(v.angles_rad[[0, -1]]), [-65.0, 65.0], atol=1e-4)
    np.testing.assert_allclose(v.ranges_m[[0, -1]], [0.0625, 4.9375], atol=1e-6)
    sensors = STAGE.run(cfg, {"dataset": rec})["sensors"]
    hs, vs = sensors["horizontal"], sensors["vertical"]
    assert hs["fov_deg"] == round(fov_of_table(table), 3)
    assert hs["beams"]["count"] == N_BEAMS
    assert hs["beams"]["max_spacing_deg"] > 1.5 * hs["beams"]["min_spacing_deg"]
    assert hs["geometry"]["beam_table"] == f"file {csv}"
    assert hs["max_range_m"] == 30.0 and hs["vertical_aperture_deg"] is None
    assert vs["fov_deg"] == 130.0 and vs["vertical_aperture_deg"] == 20.0
    assert vs["max_range_m"] == 5.0
    assert vs["geometry"]["beam_table"] == "even spacing"
    assert vs["geometry"]["datasheet"]["url"].startswith("http")
    # Every later stage takes the fan from here.
    assert with_sensor_fan(SlamConfig(), sensors).nssm_aperture_deg == hs["fov_deg"]


def test_a_table_that_does_not_fit_the_image_is_refused(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    path = tmp_path / "polar.mcap"
    _polar_recording(path, [rng.integers(0, 255, (N_RANGES, N_BEAMS), dtype=np.uint8)] * 3)
    csv = tmp_path / "short.csv"
    csv.write_text("\n".join(str(a) for a in range(N_BEAMS - 2)))
    cfg = KeyframesConfig(
        horizontal_topic=H_TOPIC, vertical_topic=V_TOPIC, horizontal_sonar=str(csv)
    )
    rec = open_recording(path, cfg)
    with pytest.raises(
        SourceError,
        match=rf"the image has {N_BEAMS} beams but the beam table of file .*short\.csv has {N_BEAMS - 2}",
    ):
        next(rec.pings("horizontal", [0]))


def test_the_fan_falls_back_to_130_for_old_sensors_and_config_wins() -> None:
    old = {"horizontal": {"T_base_sonar": np.eye(4).tolist()}}
    assert with_sensor_fan(SlamConfig(), old).nssm_aperture_deg == 130.0
    new = {"horizontal": {"T_base_sonar": np.eye(4).tolist(), "fov_deg": 27.579}}
    assert with_sensor_fan(SlamConfig(), new).nssm_aperture_deg == 27.579
    assert with_sensor_fan(SlamConfig(nssm_aperture_deg=90), new).nssm_aperture_deg == 90


@pytest.mark.parametrize("ascending", [True, False])
def test_label_images_follow_the_tables_column_order(tmp_path: Path, ascending: bool) -> None:
    rng = np.random.default_rng(5)
    images = [rng.integers(0, 255, (N_RANGES, N_BEAMS), dtype=np.uint8) for _ in range(3)]
    path = tmp_path / "labelled.mcap"
    _polar_recording(path, images, labels=True)
    table = np.linspace(-14.0, 14.0, N_BEAMS) ** 3 / 14.0**2  # uneven, ascending
    csv = tmp_path / "table.csv"
    csv.write_text("\n".join(f"{a:.6f}" for a in (table if ascending else table[::-1])))
    cfg = KeyframesConfig(
        horizontal_topic=H_TOPIC, vertical_topic=V_TOPIC, horizontal_sonar=str(csv)
    )
    ping = next(open_recording(path, cfg).pings("horizontal", [1]))
    assert ping.labels is not None
    np.testing.assert_array_equal(ping.labels, ping.image)
    np.testing.assert_array_equal(ping.image, images[1] if ascending else images[1][:, ::-1])
