"""Navigation and sensor geometry from what vehicles publish: DVL speed and gates, lever
arm, tf chains, depth from pressure, mounts from config vs the recording vs defaults,
refusals of named topics that do not exist, and `convert` keeping the recording's geometry.

Recordings here carry tiny blank sonar pings (the geometry, not the images, is tested)."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.readers import open_recording
from sonarmap.pipeline.readers.dvl import body_velocity, gate_velocity
from sonarmap.pipeline.readers.tf_tree import TfTree
from tests.fixtures import (
    P_ATM,
    mount_matrix,
    nav_samples,
    navigation_mission,
    write_navigation_bag,
)

ROOT = Path(__file__).resolve().parents[1]


def _aligned_error(run: Any, track: Any) -> tuple[float, float]:
    """(largest planar error [m], largest |z| error [m]) of a dead-reckoning track against
    the mission's navigation, after moving the track's start onto the mission's."""
    t_p, dr = run.trajectory["t_ns"], run.trajectory["dr_pose"]
    rel = (track.t_ns - t_p[0]) * 1e-9
    rel_p = (t_p - t_p[0]) * 1e-9
    ref = np.column_stack([np.interp(rel, rel_p, dr[:, i]) for i in range(3)])
    yaw0 = np.interp(rel[0], rel_p, np.unwrap(dr[:, 5])) - track.rpy_rad[0, 2]
    c, s = np.cos(yaw0), np.sin(yaw0)
    xy = track.xyz_m[:, :2] - track.xyz_m[0, :2]
    xy = np.column_stack([c * xy[:, 0] - s * xy[:, 1], s * xy[:, 0] + c * xy[:, 1]]) + ref[0, :2]
    return float(np.abs(xy - ref[:, :2]).max()), float(np.abs(track.xyz_m[:, 2] - ref[:, 2]).max())


@pytest.mark.parametrize("speed", [0.3, 1.0])
def test_a_fast_dvl_dead_reckons_as_well_as_a_slow_one(tmp_path: Path, speed: float) -> None:
    run = navigation_mission(speed)
    rec = open_recording(write_navigation_bag(tmp_path / "bag", run))
    track = rec.navigation()
    xy_err, z_err = _aligned_error(run, track)
    travelled = np.linalg.norm(np.diff(track.xyz_m[:, :2], axis=0), axis=1).sum()
    assert travelled > 0.8 * speed * 20.0
    # Mount rotation, lever arm and IMU mount undone: the same path at either speed, to
    # the recipe's discretisation (0.3 m/s: 0.016 m in 11.7 m, 1.0 m/s: 0.10 m in 25 m).
    assert xy_err < 0.005 * travelled and z_err < 1e-6, (xy_err, travelled, z_err)
    assert rec.provenance()["dvl"]["dropped"] == {}
    assert rec.source.warnings == []


def test_dvl_gates_drop_only_the_implausible_and_count_each(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    run = navigation_mission(1.0)

    def spoil(events: list[Any]) -> list[Any]:
        dvl = [e for e in events if e[1] == "/dvl/twist"]
        for k, e in enumerate(dvl[10:60:10]):  # 5 spikes at 30 m/s, 2 NaN
            e[3].twist.twist.linear.x = 30.0 if k < 5 else float("nan")
        for e in dvl[70:72]:
            e[3].twist.twist.linear.y = float("nan")
        return events

    with caplog.at_level(logging.WARNING):
        rec = open_recording(write_navigation_bag(tmp_path / "bag", run, edit=spoil))
        track = rec.navigation()
    n = len(nav_samples(run)["t"])
    (line,) = [r.getMessage() for r in caplog.records if "DVL samples" in r.getMessage()]
    assert f"dropped 2 non-finite, 5 faster than 5 m/s of {n} DVL samples" in line
    assert rec.provenance()["dvl"]["dropped"] == {"non-finite": 2, "faster than 5 m/s": 5}
    # Interpolated across (not zeroed, not held): as close as an unspoilt DVL.
    travelled = np.linalg.norm(np.diff(track.xyz_m[:, :2], axis=0), axis=1).sum()
    assert _aligned_error(run, track)[0] < 0.005 * travelled


def test_lever_arm_of_a_turning_vehicle_is_removed() -> None:
    # Turning in place at 0.5 rad/s, a DVL 1 m ahead measures 0.5 m/s sideways (rotated
    # by its mount); the base does not move.
    R = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    omega = np.array([[0.0, 0.0, 0.5]])
    v_point = np.cross(omega, [1.0, 0.0, 0.0])
    v = body_velocity(v_point @ R, R, np.array([1.0, 0.0, 0.0]), omega)
    np.testing.assert_allclose(v, 0.0, atol=1e-12)
    gated = gate_velocity(np.array([[1.0, 0, 0], [6.0, 0, 0]]), np.array([True, True]), 5.0)
    assert gated.keep.tolist() == [True, False]


def test_tf_chain_composes_through_links_and_against_their_direction() -> None:
    A, B = mount_matrix((0, 0, 30), (1, 0, 0)), mount_matrix((90, 0, 0), (0, 2, 0))
    tree = TfTree()
    tree.add("/base_link", "mount", A)
    tree.add("sonar", "mount", np.linalg.inv(B))  # published child-first
    found = tree.lookup("base_link", "sonar")
    assert found is not None and found[1] == ["base_link", "mount", "sonar"]
    np.testing.assert_allclose(found[0], A @ B, atol=1e-12)
    assert tree.lookup("base_link", "nowhere") is None


def test_pressure_depth_takes_the_surface_from_the_first_seconds(tmp_path: Path) -> None:
    run = navigation_mission(0.5, 30.0)

    def at_the_surface_first(events: list[Any]) -> list[Any]:
        # A stormy day (1.5 kPa above a standard atmosphere); the first 3 s at the surface.
        t0 = events[0][0]
        for e in events:
            if e[1] == "/bar30/pressure":
                surface = e[0] - t0 < 3_000_000_000
                p = P_ATM + 1500.0 + (0.0 if surface else e[3].fluid_pressure - P_ATM)
                e[3].fluid_pressure = p
        return events

    bag = write_navigation_bag(tmp_path / "bag", run, edit=at_the_surface_first)
    plain = open_recording(bag).navigation()
    fixed_rec = open_recording(bag, {"surface_pressure_from_first_s": 2.0})
    fixed = fixed_rec.navigation()
    late = fixed.t_ns - fixed.t_ns[0] > 4_000_000_000
    ref = np.interp(fixed.t_ns[late], run.trajectory["t_ns"], run.trajectory["dr_pose"][:, 2])
    np.testing.assert_allclose(fixed.xyz_m[late, 2], ref, atol=1e-6)
    assert np.abs(plain.xyz_m[late, 2] - ref).min() > 0.14  # 1.5 kPa is 0.15 m of water
    prov = fixed_rec.provenance()["depth"]
    assert prov["surface_pressure"] == "recording"
    assert abs(prov["surface_pressure_pa"] - (P_ATM + 1500.0)) < 1e-6


def test_depth_topic_replaces_a_pose_navigations_z(tmp_path: Path) -> None:
    run = navigation_mission(0.5, 20.0)
    bag = write_navigation_bag(tmp_path / "bag", run, navigation="odometry")
    nav = open_recording(bag).navigation()
    np.testing.assert_allclose(nav.xyz_m[:, 2], run.trajectory["dr_pose"][:, 2], atol=1e-9)
    rec = open_recording(bag, {"depth_topic": "/bar30/pressure"})
    np.testing.assert_allclose(rec.navigation().xyz_m[:, 2], nav.xyz_m[:, 2] - 0.5, atol=1e-6)
    assert rec.provenance()["depth"]["kind"] == "pressure"


def _cli(*args: str) -> Any:
    return CliRunner().invoke(app, list(args))


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    run = navigation_mission(0.5, 20.0)
    return write_navigation_bag(tmp_path_factory.mktemp("nav") / "bag", run), run


@pytest.mark.parametrize(
    ("key", "name", "listed"),
    [
        ("depth_topic", "/bar30/presure", "/bar30/pressure [sensor_msgs/msg/FluidPressure]"),
        ("dvl_topic", "/dvl/twst", "/dvl/twist [geometry_msgs/msg/TwistWithCovarianceStamped]"),
        ("imu_topic", "/imu", "/mavros/imu/data [sensor_msgs/msg/Imu]"),
    ],
)
def test_a_named_topic_not_in_the_recording_exits_2_listing_candidates(
    small_bag: tuple[Path, Any], tmp_path: Path, key: str, name: str, listed: str
) -> None:
    bag, _ = small_bag
    res = _cli(
        "run", str(bag), "--until", "keyframes", "--store", str(tmp_path / "s"),
        "--set", f"keyframes.{key}={name}", "-q",
    )  # fmt: skip
    assert res.exit_code == 2, res.output
    (line,) = res.stderr.strip().splitlines()
    assert line.startswith("error: ") and f"keyframes.{key}" in line
    assert name in line and listed in line and "Traceback" not in res.output


def test_a_depth_topic_without_depth_exits_2_naming_its_fields(
    small_bag: tuple[Path, Any], tmp_path: Path
) -> None:
    bag, _ = small_bag
    res = _cli(
        "run", str(bag), "--until", "keyframes", "--store", str(tmp_path / "s"),
        "--set", "keyframes.depth_topic=/mavros/imu/data", "-q",
    )  # fmt: skip
    assert res.exit_code == 2, res.output
    assert "has no depth, fluid_pressure or pose field" in res.stderr


def test_config_mount_wins_over_the_recording_and_is_said(
    small_bag: tuple[Path, Any], tmp_path: Path
) -> None:
    bag, run = small_bag
    res = _cli(
        "run", str(bag), "--until", "keyframes", "--store", str(tmp_path / "s"), "--json",
        "--set", "keyframes.horizontal_mount_xyz_m=[0.7, 0.0, -0.2]", "-q",
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    prov = doc["summary"]["provenance"]["horizontal_sonar"]
    assert (prov["mount_xyz"], prov["mount_rpy"]) == ("config", "recording")
    assert any("horizontal_mount_xyz_m overrides" in w for w in doc["summary"]["reader_warnings"])
    sensors = json.loads((Path(doc["stages"][0]["path"]) / "sensors.json").read_text())
    T = np.asarray(sensors["horizontal"]["T_base_sonar"])
    np.testing.assert_allclose(T[:3, 3], [0.7, 0.0, -0.2])
    np.testing.assert_allclose(T[:3, :3], run.T_base_sonar["horizontal"][:3, :3], atol=1e-9)


def test_convert_copies_the_recordings_geometry_and_invents_none(
    small_bag: tuple[Path, Any], tmp_path: Path
) -> None:
    bag, run = small_bag
    out = tmp_path / "conv.mcap"
    res = _cli("convert", str(bag), "-o", str(out), "--json")
    assert res.exit_code == 0, res.output
    rec = open_recording(out)
    for s in ("horizontal", "vertical"):
        np.testing.assert_allclose(rec.mountings()[s], run.T_base_sonar[s], atol=1e-9)
    assert rec.provenance()["vertical_sonar"]["mount_rpy"] == "recording"
    # Without geometry in the input, the output has none: a later mount setting applies
    # as config, and the default is warned, never baked in.
    bare = write_navigation_bag(tmp_path / "bare", run, tf=False)
    out2 = tmp_path / "conv2.mcap"
    res = _cli("convert", str(bare), "-o", str(out2), "--json")
    assert res.exit_code == 0, res.output
    assert "/tf_static" not in json.loads(res.stdout)["topics"]
    assert any("default mount" in w for w in json.loads(res.stdout)["warnings"])
    rec2 = open_recording(out2, {"vertical_mount_rpy_deg": (0.0, 0.0, 0.0)})
    np.testing.assert_allclose(rec2.mountings()["vertical"][:3, :3], np.eye(3), atol=1e-12)
    assert rec2.provenance()["vertical_sonar"]["mount_rpy"] == "config"
