"""Inputs that used to pass silently: sweep lists that repeat a point, a bag whose
metadata names files outside it, navigation samples that share a time at two poses or sit
1e15 m from the origin, a vertical sonar that pings far less often, warnings printed
twice by `topics`."""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import pytest
import yaml
from test_readers_mcap import T0, odom_msg
from test_robust_clocks import NAV, S, _nav, _pings, _write
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.errors import ConfigError, SourceError
from sonarmap.pipeline.engine.run.output_checks import recording_warnings
from sonarmap.pipeline.engine.store.artifact import ArtifactRef
from sonarmap.pipeline.experiments.sweep import expand
from sonarmap.pipeline.readers import open_recording, open_source
from sonarmap.schemas.topics import ODOMETRY_TYPE


@pytest.mark.parametrize(
    ("sets", "fixed", "datasets", "words"),
    [
        (["keyframes.spacing_m=,"], [], ["a.mcap"], "no value to sweep"),
        (["keyframes.spacing_m=2,3,2.0"], [], ["a.mcap"], "value 2.0 given twice (also as 2)"),
        (["keyframes.spacing_m=2", "keyframes.spacing_m=3"], [], ["a.mcap"], "already swept"),
        (["keyframes.spacing_m=2,3"], ["keyframes.spacing_m=4"], ["a.mcap"], "also swept"),
        (["keyframes.spacing_m=2"], [], ["a.mcap", "./a.mcap"], "given twice"),
    ],
    ids=["empty", "repeated-value", "key-twice", "fixed-and-swept", "dataset-twice"],
)
def test_a_sweep_that_would_count_one_point_twice_is_refused(
    sets: list[str], fixed: list[str], datasets: list[str], words: str
) -> None:
    with pytest.raises(ConfigError, match=words.replace("(", r"\(").replace(")", r"\)")):
        expand([Path(d) for d in datasets], sets, base_overrides=fixed)
    points = expand([Path("a.mcap")], ["keyframes.spacing_m=2,3", "fuse.x=a,b"])
    assert len(points) == 4  # distinct values and keys still cross


def test_a_list_setting_is_swept_by_points_in_brackets() -> None:
    """`slam.nssm_window_xy_m=1,5` would split into points [1] and [5]: refused, naming
    the bracket form, which gives one point per list."""
    def is_list(key: str) -> bool:
        return key == "slam.nssm_window_xy_m"

    with pytest.raises(ConfigError, match=r"is a list.*\[1,5\],\[2,6\]"):
        expand([Path("a.mcap")], ["slam.nssm_window_xy_m=1,5"], is_list_key=is_list)
    points = expand(
        [Path("a.mcap")],
        ["slam.nssm_window_xy_m=[1,5], [2, 6]", "keyframes.spacing_m=2,3"],
        is_list_key=is_list,
    )
    assert sorted(p.overrides[0][1] for p in points) == ["[1,5]", "[1,5]", "[2, 6]", "[2, 6]"]
    with pytest.raises(ConfigError, match="not closed"):
        expand([Path("a.mcap")], ["slam.nssm_window_xy_m=[1,5],[2"], is_list_key=is_list)


def test_sweep_of_a_list_setting_without_brackets_is_refused_by_the_cli(tmp_path: Path) -> None:
    rec = _write(tmp_path / "rec.mcap", _pings(3) + _nav([0.0, 1.0]))
    res = CliRunner().invoke(app, ["sweep", str(rec), "-s", "slam.nssm_window_xy_m=1,5"])
    assert res.exit_code == 2, res.output
    assert "is a list" in res.stderr and "runs on" not in res.stderr


@pytest.mark.parametrize("jobs", ["0", "-3"])
def test_sweep_refuses_fewer_than_one_job(tmp_path: Path, jobs: str) -> None:
    rec = _write(tmp_path / "rec.mcap", _pings(3) + _nav([0.0, 1.0]))
    res = CliRunner().invoke(app, ["sweep", str(rec), "-s", "keyframes.spacing_m=2", "-j", jobs])
    assert res.exit_code == 2, res.output
    assert "at least 1" in res.stderr and "runs on" not in res.stderr


def _bag(tmp_path: Path, listed: str) -> Path:
    bag = tmp_path / "bag"
    bag.mkdir(parents=True)
    _write(bag / "dive_0.mcap", _pings(3) + _nav([0.0, 1.0]))
    meta = {
        "rosbag2_bagfile_information": {
            "storage_identifier": "mcap",
            "relative_file_paths": [listed],
        }
    }
    (bag / "metadata.yaml").write_text(yaml.safe_dump(meta))
    return bag


@pytest.mark.parametrize("listed", ["../outside.mcap", "/etc/passwd", "sub/../../x.mcap"])
def test_bag_metadata_naming_a_file_outside_the_bag_is_refused(tmp_path: Path, listed: str) -> None:
    shutil.copy(_write(tmp_path / "outside.mcap", _pings(3)), tmp_path / "x.mcap")
    bag = _bag(tmp_path, listed)
    with pytest.raises(SourceError, match="outside the bag directory"):
        open_source(bag)


def test_a_bag_file_that_is_not_mcap_is_refused_not_called_truncated(tmp_path: Path) -> None:
    bag = _bag(tmp_path, "dive_0.mcap")
    (bag / "dive_0.mcap").write_bytes(b"garbage\n" * 10)
    with pytest.raises(SourceError, match=r"dive_0\.mcap: not an MCAP file"):
        open_source(bag)
    assert open_source(_bag(tmp_path / "ok", "dive_0.mcap")) is not None


def test_navigation_samples_sharing_a_time_at_two_poses_are_warned(tmp_path: Path) -> None:
    nav = _nav([k * 0.1 for k in range(40)])
    # Every 4th sample again at its time, 2 m away (a second publisher on the topic).
    again = [
        (t, tp, ty, odom_msg(t, 2.0 + 0.05 * k, 0.0, 0.0, 0.0))
        for k, (t, tp, ty, _) in enumerate(nav[::4])
    ]
    same = [nav[1]]  # an exact repeat (a recorder writing it twice) is not ambiguous
    events = sorted(_pings(4) + nav + again + same, key=lambda e: e[0])  # stable: first wins
    rec = open_recording(_write(tmp_path / "d.mcap", events))
    track = rec.navigation()
    [line] = [w for w in rec.source.warnings if "share their timestamp" in w]
    assert f"{NAV}: 10 of 51 navigation samples share their timestamp" in line
    assert f"first at t_ns={T0}" in line and "the first of each is used" in line
    assert len(track) == 40


def test_navigation_far_beyond_any_earth_frame_is_refused(tmp_path: Path) -> None:
    nav = [
        (T0 + k * S // 10, NAV, ODOMETRY_TYPE, odom_msg(T0 + k * S // 10, 1e15 + k, 0.0, 0.0, 0.0))
        for k in range(20)
    ]
    rec = open_recording(_write(tmp_path / "d.mcap", _pings(2) + nav))
    with pytest.raises(SourceError, match=r"navigation position 1e\+15 m from its frame's origin"):
        rec.navigation()
    utm = [
        (
            T0 + k * S // 10,
            NAV,
            ODOMETRY_TYPE,
            odom_msg(T0 + k * S // 10, 4.5e5 + k, 5.2e6, 0.0, 0.0),
        )
        for k in range(20)
    ]
    assert len(open_recording(_write(tmp_path / "utm.mcap", _pings(2) + utm)).navigation()) == 20


def _keyframes_ref(tmp_path: Path, pairing: dict[str, int], warnings: list[str]) -> ArtifactRef:
    path = tmp_path / "keyframes" / "ab"
    path.mkdir(parents=True)
    doc = {"pairing": pairing, "source": {"warnings": warnings}}
    (path / "sensors.json").write_text(json.dumps(doc))
    return ArtifactRef("keyframes", "ab", path, {})


def test_a_recording_that_loses_most_horizontal_pings_to_pairing_warns(tmp_path: Path) -> None:
    pairing = {
        "horizontal_pings": 193,
        "vertical_pings": 13,
        "pairs": 13,
        "unpaired_horizontal": 180,
    }
    kept = "{recording}: /nav: dropped 3 of 9 navigation samples"
    ref = _keyframes_ref(tmp_path, pairing, [kept])
    [line] = recording_warnings(ref, cached=False, recording="dives/rec.mcap")
    assert (
        "180 of 193 horizontal pings have no vertical ping within keyframes.pair_tolerance_s"
        in line
    )
    # A cached run repeats the reader's warnings, which only the first run's reader logged.
    # The artifact keeps no path (one key, one content): the warning names this run's file.
    again = recording_warnings(ref, cached=True, recording="dives/rec.mcap")[1]
    assert again == "dives/rec.mcap: /nav: dropped 3 of 9 navigation samples"
    even = {**pairing, "vertical_pings": 190, "pairs": 190, "unpaired_horizontal": 3}
    empty = _keyframes_ref(tmp_path / "b", even, [])
    assert recording_warnings(empty, cached=False, recording="r.mcap") == []


def test_topics_prints_each_reader_warning_once_on_one_line(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    rec = _write(tmp_path / "rec.mcap", _pings(6) + _nav([k * 0.1 for k in range(60)]))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(rec.read_bytes()[: rec.stat().st_size // 2])
    with caplog.at_level(logging.WARNING):
        res = CliRunner().invoke(app, ["topics", str(cut)], env={"COLUMNS": "60"})
    assert res.exit_code == 0, res.output
    printed = [ln for ln in res.stderr.splitlines() if "truncated or corrupt MCAP" in ln]
    logged = [r for r in caplog.records if "truncated or corrupt MCAP" in r.getMessage()]
    assert len(printed) + len(logged) == 1, (printed, logged)


def test_a_sparse_navigation_is_warned(tmp_path: Path) -> None:
    sparse = open_recording(_write(tmp_path / "s.mcap", _pings(4) + _nav([0.0, 20.0, 40.0, 60.0])))
    sparse.navigation()
    [line] = [w for w in sparse.source.warnings if "interpolated linearly" in w]
    assert f"{NAV}: navigation samples 20 s apart (median; over 5 s)" in line
    dense = open_recording(
        _write(tmp_path / "d.mcap", _pings(4) + _nav([k * 0.5 for k in range(20)]))
    )
    dense.navigation()
    assert not [w for w in dense.source.warnings if "interpolated linearly" in w]


def test_a_bag_of_symbolic_links_to_its_files_is_read(tmp_path: Path) -> None:
    files = tmp_path / "elsewhere"
    files.mkdir()
    real = _write(files / "dive_0.mcap", _pings(3) + _nav([0.0, 1.0]))
    bag = _bag(tmp_path, "dive_0.mcap")
    (bag / "dive_0.mcap").unlink()
    (bag / "dive_0.mcap").symlink_to(real)
    assert open_source(bag) is not None
