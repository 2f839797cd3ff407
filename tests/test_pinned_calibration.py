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
        ('{"sonars": {"horizontal": {}}}', "horizontal sonar: not calibrated in the file"),
        ("[1, 2]", "not a features calibration.json"),
        (None, "cannot read calibration"),
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
