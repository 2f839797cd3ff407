"""Campaign 5 (navigation as field recordings publish it): conventions that mapped metres
off with exit 0 and no word. Each is now read right or warned, naming the cause."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from sonarmap.pipeline.readers.depth import depth_doubts
from sonarmap.pipeline.readers.geometry_checks import navigation_doubts, ned_convention
from sonarmap.pipeline.readers.recording import ReaderOptions
from sonarmap.pipeline.readers.roles import detect_roles
from sonarmap.pipeline.readers.source_types import TopicInfo

SONARS = [
    TopicInfo("/sonar/horizontal", "marine_acoustic_msgs/msg/ProjectedSonarImage", 10, 0, 9, 10),
    TopicInfo("/sonar/vertical", "marine_acoustic_msgs/msg/ProjectedSonarImage", 10, 0, 9, 10),
]
DVL = TopicInfo("/dvl/twist", "geometry_msgs/msg/TwistWithCovarianceStamped", 10, 0, 9, 10)
IMU = TopicInfo("/imu/data", "sensor_msgs/msg/Imu", 10, 0, 9, 10)


def _pose(topic: str) -> TopicInfo:
    return TopicInfo(topic, "geometry_msgs/msg/PoseWithCovarianceStamped", 10, 0, 9, 10)


def test_a_depth_sensors_pose_beside_a_dvl_and_an_imu_is_the_depth_not_the_navigation() -> None:
    # BlueROV2 style: depth fed as a pose with only z set. It became the navigation (the
    # DVL and IMU ignored): 1 keyframe, the map 5.4 m off.
    path = Path("dive.mcap")
    options = ReaderOptions.from_config(None)
    roles = detect_roles(path, [*SONARS, DVL, IMU, _pose("/bar30/depth")], options)
    assert (roles.navigation, roles.dvl, roles.imu) == (None, "/dvl/twist", "/imu/data")
    assert roles.depth == "/bar30/depth"
    # Configured as the depth topic, a pose is never also the navigation.
    options = ReaderOptions.from_config({"depth_topic": "/bar30/pose_ned"})
    roles = detect_roles(path, [*SONARS, DVL, IMU, _pose("/bar30/pose_ned")], options)
    assert (roles.navigation, roles.depth, roles.dvl) == (None, "/bar30/pose_ned", "/dvl/twist")
    # Without a DVL and an IMU there is nothing else to navigate by: it stays navigation.
    roles = detect_roles(
        path, [*SONARS, _pose("/odometry/depth_fused")], ReaderOptions.from_config(None)
    )
    assert roles.navigation == "/odometry/depth_fused"


def test_a_depth_above_the_surface_or_covering_part_of_the_dive_is_warned() -> None:
    t = np.arange(100, dtype=np.int64) * 10**9
    assert depth_doubts(t, np.full(100, 2.0), t) == []
    (above,) = depth_doubts(t, np.full(100, -2.0), t)  # z up read as depth: 2 m above
    assert above.startswith("the depth puts the vehicle 2 m above the surface (median)")
    (part,) = depth_doubts(t[:30], np.full(30, 2.0), t)  # the sensor stopped at 30 %
    assert part.startswith("depth samples cover 29 % of the navigation's 99 s")


def test_pings_outside_the_navigation_and_a_vehicle_on_its_side_are_warned() -> None:
    t = np.arange(100, dtype=np.int64)
    level = np.zeros((70, 3))
    (late,) = navigation_doubts(t, t[30:], level)
    assert late.startswith("30 of 100 horizontal pings (30 %) fall outside the navigation's span")
    assert navigation_doubts(t, t[2:], level) == []  # a few at the edges are usual
    upside_down = np.tile([np.pi, 0.0, 0.3], (70, 1))  # FRD read as FLU, or a (w, x, y, z)
    (tilted,) = navigation_doubts(t[30:], t[30:], upside_down)
    assert "rolled or pitched over 45 deg for 100 % of its samples (median |roll| 180" in tilted
    glider = np.tile([0.0, np.deg2rad(-25.0), 0.0], (70, 1))
    assert navigation_doubts(t[30:], t[30:], glider) == []


def test_frames_named_ned_or_frd_by_rep_105_are_recognised() -> None:
    def odometry(frame: str, child: str = "") -> SimpleNamespace:
        return SimpleNamespace(header=SimpleNamespace(frame_id=frame), child_frame_id=child)

    assert ned_convention(odometry("odom_ned", "base_link_frd")) == (True, True)
    assert ned_convention(odometry("NED", "base_link")) == (True, False)
    assert ned_convention(odometry("odom", "base_link")) == (False, False)
    assert ned_convention(odometry("map_aligned")) == (False, False)  # "...ned" is no NED frame
    assert ned_convention(odometry("pinned")) == (False, False)
    assert ned_convention(None) == (False, False)


def test_a_pose_in_ned_and_frd_is_the_same_pose_in_enu_and_flu() -> None:
    from scipy.spatial.transform import Rotation

    from sonarmap.pipeline.readers.navigation import FLU_TO_FRD, NED_TO_ENU, enu_flu

    # A vehicle 2 m deep, 10 m east and 5 m north, heading north-east, pitched 10 deg nose up.
    xyz_enu = np.array([[10.0, 5.0, -2.0]])
    r_enu_flu = Rotation.from_euler("ZYX", [45.0, -10.0, 0.0], degrees=True)
    xyz_ned = xyz_enu @ NED_TO_ENU  # NED_TO_ENU is its own inverse
    r_ned_frd = Rotation.from_matrix(NED_TO_ENU @ r_enu_flu.as_matrix() @ FLU_TO_FRD)
    assert np.allclose(xyz_ned, [[5.0, 10.0, 2.0]])  # north, east, down
    # NED heading of north-east is 45 deg clockwise from north: the same 45 deg.
    assert np.isclose(r_ned_frd.as_euler("ZYX", degrees=True)[0], 45.0)
    xyz, q = enu_flu(xyz_ned, r_ned_frd.as_quat()[None], True, True)
    assert np.allclose(xyz, xyz_enu)
    assert np.allclose(Rotation.from_quat(q).as_matrix()[0], r_enu_flu.as_matrix(), atol=1e-12)


def test_imu_rates_in_degrees_per_second_are_warned() -> None:
    # A 2-goal dive's IMU in deg/s: dead reckoning 7.7 m off, only the generic SLAM warning.
    from scipy.spatial.transform import Rotation

    from sonarmap.pipeline.readers.navigation_checks import rate_unit_doubt

    t = np.arange(200, dtype=np.int64) * 10**8  # 10 Hz
    yaw_rate = np.where(np.arange(200) < 100, 0.2, -0.1)  # rad/s: turns both ways
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (yaw_rate[:-1] + yaw_rate[1:]) * 0.1)])
    q = Rotation.from_euler("z", yaw[:, None]).as_quat()
    w = np.stack([np.zeros(200), np.zeros(200), yaw_rate], axis=1)
    assert rate_unit_doubt(t, q, w) is None
    doubt = rate_unit_doubt(t, q, np.rad2deg(w))
    assert doubt is not None and doubt.startswith("its angular rates add up to 57x the turn")
    assert rate_unit_doubt(t, np.tile([0, 0, 0, 1.0], (200, 1)), np.rad2deg(w)) is None  # no turn
