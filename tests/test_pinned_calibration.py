"""`features.calibration_from` / `features.pinned_bands`: a whole calibration pinned (every
band's thresholds, per sonar), as a user maps dives of one sonar with one calibration, or
keeps a growing recording's detections when its calibration sample would move."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
from pydantic import ValidationError
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.config.load import load_config
from sonarmap.pipeline.graph import all_stages, extra_sections
from sonarmap.pipeline.readers.pinned_calibration import pin_calibration
from sonarmap.stages.features.config import FeaturesConfig
from tests.fixtures.recordings import small_recording


def _run(rec: Path, store: Path, *sets: str) -> Any:
    args = ["run", str(rec), "--store", str(store), "--until", "features", "--json", "-j", "1"]
    for s in sets:
        args += ["--set", s]
    return CliRunner().invoke(app, args)


def _features_dir(res: Any) -> Path:
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    return Path(next(s["path"] for s in doc["stages"] if s["stage"] == "features"))


@pytest.fixture(scope="module")
def measured(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """A recording, its store, and the features artifact of a run that measured."""
    root = tmp_path_factory.mktemp("pinned")
    rec = small_recording(root / "rec.mcap", duration_s=20.0)
    return rec, root / "s", _features_dir(_run(rec, root / "s"))


def test_its_own_calibration_pinned_detects_the_same_features(
    measured: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    rec, store, first = measured
    copy = tmp_path / "elsewhere.json"  # the file's path and name are not keyed
    copy.write_bytes((first / "calibration.json").read_bytes())
    res = _run(rec, store, f"features.calibration_from={first / 'calibration.json'}")
    pinned = _features_dir(res)
    assert pinned != first  # other settings, another artifact ...
    assert pq.read_table(pinned / "features.parquet").equals(
        pq.read_table(first / "features.parquet")
    )  # ... with the same detections, each keyframe's unit reused (keyed by thresholds)
    (features,) = [s for s in json.loads(res.stdout)["stages"] if s["stage"] == "features"]
    assert features["units"][1] == 0, features["units"]
    doc = json.loads((pinned / "calibration.json").read_text())
    assert doc["pinned"]["bands"] == "features.pinned_bands" and doc["measured"] == []
    assert _features_dir(_run(rec, store, f"features.calibration_from={copy}")) == pinned


def test_a_pinned_band_is_the_one_detection_uses(measured: tuple[Path, Path, Path]) -> None:
    rec, store, first = measured
    doc = json.loads((first / "calibration.json").read_text())
    bands = {
        s: {
            "band_edges_m": e["band_edges_m"],
            "threshold_factor": [b["threshold_factor"] for b in e["bands"]],
            "intensity_floor_levels": [255.0] * len(e["bands"]),  # nothing passes
            "denoise": e["denoise"],
        }
        for s, e in doc["sonars"].items()
    }
    res = _run(rec, store, "features.pinned_bands=" + json.dumps(bands))
    assert pq.read_table(_features_dir(res) / "features.parquet").num_rows == 0


def test_bands_of_another_range_window_are_refused_in_one_line(
    measured: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    rec, store, first = measured
    doc = json.loads((first / "calibration.json").read_text())
    entry = doc["sonars"]["vertical"]
    entry["band_edges_m"] = [2 * e for e in entry["band_edges_m"]]  # a sonar set to 2x range
    other = tmp_path / "other.json"
    other.write_text(json.dumps(doc))
    res = _run(rec, store, f"features.calibration_from={other}")
    assert res.exit_code == 2, res.output
    line = res.stderr.strip().splitlines()[-1]
    assert "features.pinned_bands: vertical sonar: 8 range bands over" in line, line
    assert "pin a calibration of the same sonar range" in line


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        ("{not json", "not JSON"),
        ('{"sonars": {"horizontal": {}}}', "sonars.horizontal: not calibrated in the file"),
        ("[1, 2]", "not a features calibration.json"),
        (None, "cannot read calibration"),
        # campaign 15 #1, #8, #12: an internal error, confusing lines, silent defaults
        ("[" * 100_000 + "]" * 100_000, "JSON nested too deeply"),
        ('{"sonars": {}, "sonars": {}}', "the key 'sonars' is given twice"),
        ('{"sonars": {"sidescan": {}}}', "unknown sonar 'sidescan'"),
        (
            json.dumps({"sonars": {"horizontal": {"bands": [], "band_edges_m": [0, 1]}}}),
            "sonars.horizontal.denoise: expected the filter's name",
        ),
        (
            json.dumps(
                {
                    "sonars": {
                        "horizontal": {"bands": [1], "band_edges_m": [0, 1], "denoise": "none"}
                    }
                }
            ),
            "sonars.horizontal.bands[0]: expected an object with 'threshold_factor'",
        ),
        (
            json.dumps(
                {
                    "sonars": {
                        "horizontal": {"bands": [], "band_edges_m": "0,3.75", "denoise": "none"}
                    }
                }
            ),
            "sonars.horizontal.band_edges_m: expected a list of numbers",
        ),
    ],
)
def test_a_file_that_is_not_a_calibration_is_refused_naming_the_setting(
    tmp_path: Path, content: str | None, needle: str
) -> None:
    bad = tmp_path / "bad.json"
    if content is not None:  # None: no such file
        bad.write_text(content)
    config = tmp_path / "pinned.yaml"
    config.write_text(f"features:\n  calibration_from: {bad}\n")
    res = CliRunner().invoke(app, ["config", "check", str(config)])
    assert res.exit_code == 2, res.output
    assert f"features.calibration_from: {bad}: " in res.stderr and needle in res.stderr


def test_pinned_bands_are_checked_as_every_setting() -> None:
    good = {"band_edges_m": [0, 1, 2], "threshold_factor": [2, 2], "intensity_floor_levels": [9, 9]}
    with pytest.raises(ValidationError, match="pin both sonars"):
        FeaturesConfig(pinned_bands={"horizontal": good})
    bad = {**good, "band_edges_m": [0, 2, 1]}
    with pytest.raises(ValidationError, match="must increase"):
        FeaturesConfig(pinned_bands={"horizontal": good, "vertical": bad})
    short = {**good, "threshold_factor": [2]}
    with pytest.raises(ValidationError, match="2 bands"):
        FeaturesConfig(pinned_bands={"horizontal": good, "vertical": short})
    assert "pinned_bands" not in FeaturesConfig().model_dump()  # unpinned: keys unchanged


def test_a_threshold_set_beside_a_pinned_calibration_is_refused() -> None:
    """Campaign 15 #2, #5: a floor, factor or filter set beside the pin was ignored, yet
    recorded as pinned; a pin of another band count passed `config check`."""
    band = {"band_edges_m": [0, 1, 2], "threshold_factor": [2, 2], "intensity_floor_levels": [9, 9]}
    pins = {"horizontal": band, "vertical": band}
    assert FeaturesConfig(pinned_bands=pins, range_bands=2).pinned_bands is not None
    for name, value in [("intensity_floor", 60.0), ("threshold_factor", 2.0), ("denoise", "none")]:
        with pytest.raises(ValidationError, match=f"{name} .* cannot be set beside pinned_bands"):
            FeaturesConfig(pinned_bands=pins, range_bands=2, **{name: value})
    with pytest.raises(
        ValidationError, match="horizontal sonar has 2 range bands, range_bands is 8"
    ):
        FeaturesConfig(pinned_bands=pins)


def test_the_training_sections_calibration_is_read_and_a_home_path_expanded(
    measured: tuple[Path, Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Campaign 15 #3, #10: `training.features.calibration_from` was never read (a missing
    file passed, the train key did not move); `~` was not expanded."""
    _, _, features = measured
    monkeypatch.setenv("HOME", str(features))
    sets = ["training.features.calibration_from=~/calibration.json"]
    config = pin_calibration(load_config(all_stages(), None, sets, extra_sections()))
    assert config.training.features.pinned_bands is not None  # type: ignore[attr-defined]
    yaml = tmp_path / "c.yaml"
    yaml.write_text(f"training:\n  features:\n    calibration_from: {tmp_path / 'nope.json'}\n")
    res = CliRunner().invoke(app, ["config", "check", str(yaml)])
    assert res.exit_code == 2 and "training.features.calibration_from" in res.stderr, res.output


def test_config_dump_keeps_the_pin(tmp_path: Path) -> None:
    """Campaign 15 #4: the dump left `calibration_from` out, so a dumped config reused
    measured the thresholds it was meant to pin."""
    res = CliRunner().invoke(app, ["config", "dump", "--set", "features.calibration_from=c.json"])
    assert res.exit_code == 0, res.output
    assert "  calibration_from: c.json\n" in res.stdout
    assert "calibration_from" not in json.dumps(
        FeaturesConfig(calibration_from="c.json").model_dump()
    )


def test_the_report_says_a_whole_calibration_is_pinned() -> None:
    """Campaign 15 #13: it said "calibrated from the recording", printed a dict and None."""
    from sonarmap.stages.evaluate.front_end import front_end_markdown

    sonar = {"features_per_keyframe": 10.0, "expected_false_alarms_per_ping": None,
             "background_bands": [0], "background_detection_rate": 0.001,
             "keyframes_clipped": 0, "features_dropped": 0}  # fmt: skip
    text = "\n".join(front_end_markdown({
        "stated_false_alarm_rate_per_cell": 0.001, "measured": [], "sonars": {"horizontal": sonar},
        "pinned": {"bands": "features.pinned_bands"}, "fused_share_of_horizontal_features": 0.1,
        "objects_per_keyframe": 1.0}))  # fmt: skip
    assert "## Front end (detection thresholds pinned by the config)" in text
    assert "every band's floor, CFAR factor and filter (features.pinned_bands)" in text
    assert "| horizontal | 10.0 | - |" in text and "None" not in text and "{" not in text


def test_a_sweep_over_two_copies_of_one_calibration_is_refused(
    measured: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    """Campaign 15 #7: two files of one content ran the same point twice."""
    rec, _, features = measured
    copy = tmp_path / "copy.json"
    copy.write_bytes((features / "calibration.json").read_bytes())
    res = CliRunner().invoke(app, [
        "sweep", str(rec), "--store", str(tmp_path / "s"), "--out", str(tmp_path / "o"),
        "--set", f"features.calibration_from={features / 'calibration.json'},{copy}",
    ])  # fmt: skip
    assert res.exit_code == 2, res.output
    assert "are the same point (the files they name hold the same content)" in res.stderr
    assert not (tmp_path / "s" / "keyframes").exists()  # refused before the first run
