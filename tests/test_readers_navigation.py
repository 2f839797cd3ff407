"""Navigation: Odometry/PoseStamped/PoseWithCovarianceStamped and DVL + IMU + depth
dead reckoning (docs/authors-code.md section 6.7) from a ROS 1 bag."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Writer as Bag1Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from test_readers_mcap import write_synthetic
from test_readers_oculus import _oculus_ping, _ros1_header

from sonarmap.pipeline.formats.rosmsg import custom_msg_texts, ros2_typestore
from sonarmap.pipeline.readers import open_recording
from sonarmap.pipeline.readers.navigation import dead_reckon, pose_track
from sonarmap.stages.kernels.geometry import rpy_from_quat as quat_to_rpy

DVL_MSG = "Header header\ngeometry_msgs/Vector3 velocity\nfloat64 temperature\nfloat64 altitude\nfloat64 time\n"
DEPTH_MSG = (
    "Header header\nfloat32 time\nfloat32 pressure_abs\nfloat32 pressure_diff\n"
    "float32 temperature\nfloat32 depth\n"
)


def _quat(yaw: np.ndarray) -> np.ndarray:
    return np.column_stack([0 * yaw, 0 * yaw, np.sin(yaw / 2), np.cos(yaw / 2)])


def test_dead_reckon_integrates_body_velocity_and_gates_spikes() -> None:
    t = np.arange(0, 201, dtype=np.int64) * 100_000_000  # 20 s at 10 Hz
    yaw = 0.3 + 0.05 * t * 1e-9
    v = np.column_stack([np.full(len(t), 0.3), np.zeros(len(t)), np.zeros(len(t))])
    v[50] = (4.0, 0.0, 0.0)  # a DVL glitch above the 0.5 m/s gate
    track = dead_reckon(t, v, t, _quat(yaw), t, np.full(len(t), 3.0), 0.5)
    # Analytic: speed 0.3 along heading yaw - yaw0 = 0.05 s. The recipe rotates each step
    # by the yaw at its end: error <= v * T * (yaw rate * dt / 2) = 0.3 * 20 * 0.0025 m.
    s = t * 1e-9
    x, y = 0.3 / 0.05 * np.sin(0.05 * s), 0.3 / 0.05 * (1 - np.cos(0.05 * s))
    np.testing.assert_allclose(track.xyz_m[:, 0], x, atol=0.015)
    np.testing.assert_allclose(track.xyz_m[:, 1], y, atol=0.015)
    spiked = dead_reckon(t, v, t, _quat(yaw), t, np.full(len(t), 3.0), 10.0)
    assert spiked.xyz_m[-1, 0] - track.xyz_m[-1, 0] > 0.3  # without the gate: +0.37 m
    np.testing.assert_allclose(track.xyz_m[:, 2], -3.0)
    np.testing.assert_allclose(track.rpy_rad[:, 2], 0.05 * s, atol=1e-9)


def test_quaternion_to_rpy_matches_scipy() -> None:
    from scipy.spatial.transform import Rotation

    rpy = np.array([[0.1, -0.2, 2.5], [-1.0, 0.4, -3.0]])
    q = Rotation.from_euler("xyz", rpy).as_quat()
    np.testing.assert_allclose(quat_to_rpy(q), rpy, atol=1e-12)


def test_pose_stamped_and_pose_with_covariance_decode() -> None:
    t = ros2_typestore().types
    pose = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=1.0, y=2.0, z=-3.0),
        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(0.25), w=np.cos(0.25)),
    )
    header = t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="odom"
    )
    stamped = t["geometry_msgs/msg/PoseStamped"](header=header, pose=pose)
    cov = t["geometry_msgs/msg/PoseWithCovarianceStamped"](
        header=header,
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
    )
    track = pose_track([(2, cov), (1, stamped), (2, stamped)])
    np.testing.assert_array_equal(track.t_ns, [1, 2])
    np.testing.assert_allclose(track.xyz_m, [[1, 2, -3], [1, 2, -3]])
    np.testing.assert_allclose(track.rpy_rad[:, 2], 0.5)


def _store() -> Any:
    store = get_typestore(Stores.ROS1_NOETIC)
    for name, text in custom_msg_texts().items():
        store.register(get_types_from_msg(text, name))
    store.register(get_types_from_msg(DVL_MSG, "rti_dvl/msg/DVL"))
    store.register(get_types_from_msg(DEPTH_MSG, "bar30_depth/msg/Depth"))
    return store


def test_ros1_bag_without_odometry_uses_dvl_imu_depth(tmp_path: Path) -> None:
    mcap_path = tmp_path / "d.mcap"
    write_synthetic(mcap_path, n_pings=30, labels=False, navigation=False)
    store, t1 = _store(), _store().types
    bag_path = tmp_path / "auv.bag"
    from mcap.reader import make_reader

    t_nav = 1_700_000_000_000_000_000 + np.arange(-5, 160, dtype=np.int64) * 100_000_000
    yaw = 1.0 + 0.02 * (t_nav - t_nav[0]) * 1e-9
    events: list[tuple[int, str, str, Any]] = []
    with mcap_path.open("rb") as f:
        for schema, channel, m in make_reader(f).iter_messages():
            msg2 = ros2_typestore().deserialize_cdr(m.data, schema.name)
            topic = (
                "/sonar_oculus_node/M750d/ping"
                if "horizontal" in channel.topic
                else "/sonar_oculus_node/M1200d/ping"
            )
            msg, typ = _oculus_ping(t1, msg2, m.log_time, compressed=False)
            events.append((m.log_time, topic, typ, msg))
    vec = t1["geometry_msgs/msg/Vector3"]
    for k, t in enumerate(t_nav.tolist()):
        h = _ros1_header(t1, t, "base_link")
        events.append(
            (
                t,
                "/rti/body_velocity/raw",
                "rti_dvl/msg/DVL",
                t1["rti_dvl/msg/DVL"](
                    header=h,
                    velocity=vec(x=0.4, y=0.0, z=0.0),
                    temperature=10.0,
                    altitude=5.0,
                    time=0.0,
                ),
            )
        )
        q = _quat(np.array([yaw[k]]))[0]
        events.append(
            (
                t,
                "/vn100/imu/raw",
                "sensor_msgs/msg/Imu",
                t1["sensor_msgs/msg/Imu"](
                    header=h,
                    orientation=t1["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
                    orientation_covariance=np.zeros(9),
                    angular_velocity=vec(x=0.0, y=0.0, z=0.0),
                    angular_velocity_covariance=np.zeros(9),
                    linear_acceleration=vec(x=0.0, y=0.0, z=0.0),
                    linear_acceleration_covariance=np.zeros(9),
                ),
            )
        )
        events.append(
            (
                t,
                "/bar30/depth/raw",
                "bar30_depth/msg/Depth",
                t1["bar30_depth/msg/Depth"](
                    header=h,
                    time=0.0,
                    pressure_abs=0.0,
                    pressure_diff=0.0,
                    temperature=0.0,
                    depth=4.0,
                ),
            )
        )
    events.sort(key=lambda e: (e[0], e[1]))
    with Bag1Writer(bag_path) as bag:
        conns: dict[str, Any] = {}
        for t, topic, typ, msg in events:
            if topic not in conns:
                conns[topic] = bag.add_connection(topic, typ, typestore=store)
            bag.write(conns[topic], t, store.serialize_ros1(msg, typ))
    rec = open_recording(bag_path)
    assert (rec.roles.dvl, rec.roles.imu, rec.roles.depth) == (
        "/rti/body_velocity/raw",
        "/vn100/imu/raw",
        "/bar30/depth/raw",
    )
    nav = rec.navigation()
    s = (nav.t_ns - t_nav[0]) * 1e-9
    np.testing.assert_allclose(nav.xyz_m[:, 0], 0.4 / 0.02 * np.sin(0.02 * s), atol=0.01)
    np.testing.assert_allclose(nav.xyz_m[:, 1], 0.4 / 0.02 * (1 - np.cos(0.02 * s)), atol=0.01)
    np.testing.assert_allclose(nav.xyz_m[:, 2], -4.0)
    from sonarmap.stages.keyframes import STAGE, KeyframesConfig

    rows = STAGE.run(KeyframesConfig(), {"dataset": rec})["keyframes"].to_pylist()
    assert [r["reason"] for r in rows[:3]] == ["first", "translation", "translation"]
    assert all(r["gt_x_m"] is None for r in rows)
