"""Field twins: one simulated mission re-encoded the way real vehicles' drivers publish
it (rosbag2, renamed topics and frames, a two-link tf chain, DVL + IMU + FluidPressure in
their own mounted frames, an Odometry-only navigation) maps, with no config at all, to the
same world as the canonical recording: keyframe depth within 0.10 m, fused-map voxels
overlapping the canonical ones (IoU >= 0.8). Polar `sensor_msgs/Image` sonars with an
uneven beam table map the same world given the table as a file (and their topics)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from scipy.spatial.transform import Rotation

from tests.fixtures import (
    DVL_RPY,
    DVL_XYZ,
    IMU_RPY,
    dvl_imu_pressure,
    mount_matrix,
    nav_samples,
    ros2_types,
    ros_header,
    tf_stamped,
    write_bag,
)

ROOT = Path(__file__).resolve().parents[1]
VOXEL_M = 0.1
SCENE = "moorings"

H_TOPIC, V_TOPIC = "/oculus_m750d/sonar_image", "/oculus_m1200d/sonar_image"
H_FRAME, V_FRAME = "m750d_link", "m1200d_link"
T_BASE_MOUNT = np.eye(4)
T_BASE_MOUNT[:3, :3] = Rotation.from_euler("xyz", [0.0, 0.1, 0.3]).as_matrix()
T_BASE_MOUNT[:3, 3] = (0.35, -0.05, 0.12)
"""base_link -> sonar_mount: the bracket both sonars hang from (tilted, offset)."""


@dataclass
class Canonical:
    path: Path
    run: Any
    world: set[tuple[int, int, int]]
    keyframes: Any


def _engine(dataset: Path, store: Path, overrides: tuple[str, ...] = ()) -> dict[str, Path]:
    """keyframes -> features -> fuse on `dataset`; artifact directory per stage."""
    from sonarmap.pipeline.engine.run.runner import execute, plan
    from sonarmap.pipeline.engine.run.session import make_context
    from sonarmap.pipeline.graph import default_graph
    from sonarmap.stages.features.stage import STAGE as FEATURES
    from sonarmap.stages.fuse.stage import STAGE as FUSE
    from sonarmap.stages.keyframes import STAGE as KEYFRAMES

    ctx = make_context(
        dataset,
        stages=[KEYFRAMES, FEATURES, FUSE],
        graph=default_graph(),
        overrides=overrides,
        store_dir=store,
    )
    result = execute(plan(ctx.stages, ctx.config, ctx.dataset, ctx.store), *_rest(ctx))
    return {r.stage: Path(r.path) for r in result.stages}


def _rest(ctx: Any) -> tuple[Any, Any, Any]:
    return ctx.config, ctx.dataset, ctx.store


def _pose_matrices(kf: Any) -> np.ndarray:
    cols = ["x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad"]
    p = np.column_stack([kf[c].to_numpy() for c in cols])
    T = np.tile(np.eye(4), (len(p), 1, 1))
    T[:, :3, :3] = Rotation.from_euler("ZYX", p[:, [5, 4, 3]]).as_matrix()
    T[:, :3, 3] = p[:, :3]
    return T


def _fused_world(arts: dict[str, Path], align: np.ndarray | None = None) -> np.ndarray:
    """Fused points in the world: keyframe pose @ the artifact's horizontal mount @ point."""
    kf = pq.read_table(arts["keyframes"] / "keyframes.parquet")
    sensors = json.loads((arts["keyframes"] / "sensors.json").read_text())
    T_bs = np.asarray(sensors["horizontal"]["T_base_sonar"])
    fused = pq.read_table(arts["fuse"] / "fused.parquet")
    T_wb = _pose_matrices(kf)
    if align is not None:
        T_wb = align @ T_wb
    T = T_wb[fused["keyframe_id"].to_numpy()] @ T_bs
    p = np.column_stack([fused[c].to_numpy() for c in ("x_m", "y_m", "z_m")])
    return np.einsum("nij,nj->ni", T[:, :3, :3], p) + T[:, :3, 3]


def _voxels(points: np.ndarray) -> set[tuple[int, int, int]]:
    return set(map(tuple, np.floor(points / VOXEL_M).astype(np.int64).tolist()))


def _iou(a: set[Any], b: set[Any]) -> float:
    return len(a & b) / max(len(a | b), 1)


@pytest.fixture(scope="module")
def canonical(tmp_path_factory: pytest.TempPathFactory) -> Canonical:
    from sonarmap.pipeline.formats.simulation import write_simulation
    from sonarmap.sim.config import SimConfig
    from sonarmap.sim.dataset import simulate
    from sonarmap.sim.scene import load_scene

    scene = ROOT / "configs" / "scenes" / f"{SCENE}.yaml"
    base = SimConfig()
    mission = base.mission.model_copy(update={"n_goals": 2, "duration_s": 30.0})
    run = simulate(load_scene(scene), base.model_copy(update={"mission": mission}), 3)
    tmp = tmp_path_factory.mktemp("twins")
    path = tmp / "canonical.mcap"
    write_simulation(run, path, scene_yaml=scene.read_text())
    arts = _engine(path, tmp / "store")
    kf = pq.read_table(arts["keyframes"] / "keyframes.parquet")
    assert len(kf) >= 5
    return Canonical(path, run, _voxels(_fused_world(arts)), kf)


# --- re-encoding as drivers publish ------------------------------------------------------


def write_twin(canonical: Canonical, out: Path, navigation: str) -> Path:
    """Re-encode the canonical recording as a rosbag2 (MCAP storage) with the drivers'
    names; `navigation` is "odometry" (a renamed Odometry) or "dvl" (DVL + IMU + Bar30)."""
    from mcap.reader import make_reader

    store = ros2_types()
    t = store.types
    rename = {"/sonar/horizontal": (H_TOPIC, H_FRAME), "/sonar/vertical": (V_TOPIC, V_FRAME)}
    mounts = canonical.run.T_base_sonar
    events: list[tuple[int, str, str, Any]] = []
    with canonical.path.open("rb") as f:
        for schema, channel, m in make_reader(f).iter_messages():
            if channel.topic in rename or (
                navigation.startswith("odometry") and channel.topic == "/odometry/dead_reckoning"
            ):
                msg = store.deserialize_cdr(m.data, schema.name)
                topic, frame = rename.get(channel.topic, ("/bluerov2/odometry", ""))
                if frame:
                    msg.header.frame_id = frame
                elif navigation == "odometry_ned":
                    _to_ned_frd(msg)
                events.append((m.log_time, topic, schema.name, msg))
    t0 = int(canonical.run.trajectory["t_ns"][0])
    inv_mount = np.linalg.inv(T_BASE_MOUNT)
    transforms = [
        tf_stamped(t, t0, "base_link", "sonar_mount", T_BASE_MOUNT),
        tf_stamped(t, t0, "sonar_mount", H_FRAME, inv_mount @ mounts["horizontal"]),
        tf_stamped(t, t0, "sonar_mount", V_FRAME, inv_mount @ mounts["vertical"]),
    ]
    if navigation == "dvl":
        T_dvl, T_imu = mount_matrix(DVL_RPY, DVL_XYZ), mount_matrix(IMU_RPY, (0.0, 0.05, 0.02))
        transforms += [
            tf_stamped(t, t0, "base_link", "dvl_link", T_dvl),
            tf_stamped(t, t0, "base_link", "imu_link", T_imu),
        ]
        events += dvl_imu_pressure(t, nav_samples(canonical.run), T_dvl, T_imu)
    events.append(
        (
            t0,
            "/tf_static",
            "tf2_msgs/msg/TFMessage",
            t["tf2_msgs/msg/TFMessage"](transforms=transforms),
        )
    )
    return write_bag(out, store, events)


def _to_ned_frd(odometry: Any) -> None:
    """An ENU / FLU Odometry message rewritten as a NED / FRD driver publishes it (REP 105)."""
    enu_to_ned = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    p, o = odometry.pose.pose.position, odometry.pose.pose.orientation
    p.x, p.y, p.z = p.y, p.x, -p.z
    r = Rotation.from_quat([o.x, o.y, o.z, o.w]).as_matrix()
    q = Rotation.from_matrix(enu_to_ned @ r @ np.diag([1.0, -1.0, -1.0])).as_quat()
    o.x, o.y, o.z, o.w = (float(v) for v in q)
    odometry.header.frame_id, odometry.child_frame_id = "odom_ned", "base_link_frd"


def _compare(canonical: Canonical, arts: dict[str, Path], align: bool) -> tuple[float, float]:
    """(largest keyframe depth difference [m], fused-map voxel IoU) against the canonical.
    `align`: the twin's world starts at its first keyframe (dead reckoning has no
    absolute origin), so it is moved onto the canonical's first keyframe."""
    kf = pq.read_table(arts["keyframes"] / "keyframes.parquet")
    ref = canonical.keyframes
    t_ref = ref["t_ns"].to_numpy()
    idx = np.clip(np.searchsorted(t_ref, kf["t_ns"].to_numpy()), 0, len(t_ref) - 1)
    dz = np.abs(kf["z_m"].to_numpy() - ref["z_m"].to_numpy()[idx])
    M = None
    if align:
        first = kf["t_ns"].to_numpy()[0]
        assert first == t_ref[0]
        M = _pose_matrices(ref.slice(0, 1))[0] @ np.linalg.inv(_pose_matrices(kf.slice(0, 1))[0])
    return float(dz.max()), _iou(_voxels(_fused_world(arts, M)), canonical.world)


# --- the targets ----------------------------------------------------------------------


def test_odometry_twin_with_renamed_topics_frames_and_tf_chain_maps_the_same_world(
    canonical: Canonical, tmp_path: Path
) -> None:
    twin = write_twin(canonical, tmp_path / "bluerov2_odom", "odometry")
    arts = _engine(twin, tmp_path / "store")
    dz, iou = _compare(canonical, arts, align=False)
    assert dz <= 0.10 and iou >= 0.99, (dz, iou)
    sensors = json.loads((arts["keyframes"] / "sensors.json").read_text())
    for s in ("horizontal", "vertical"):
        np.testing.assert_allclose(
            sensors[s]["T_base_sonar"], canonical.run.T_base_sonar[s], atol=1e-9
        )
    prov = sensors["provenance"]
    assert prov["horizontal_sonar"]["topic"] == H_TOPIC
    assert prov["horizontal_sonar"]["tf_chain"] == ["base_link", "sonar_mount", H_FRAME]
    assert (
        prov["vertical_sonar"]["mount_xyz"] == prov["vertical_sonar"]["mount_rpy"] == ("recording")
    )
    assert prov["navigation"] == {
        "topic": "/bluerov2/odometry",
        "type": "nav_msgs/msg/Odometry",
        "source": "recording",
    }
    assert sensors["source"]["warnings"] == []


def test_odometry_in_ned_and_frd_maps_the_same_world(canonical: Canonical, tmp_path: Path) -> None:
    # Read as ENU it mapped mirrored, the vehicle 2 m above the water (1.97 m off), silently.
    twin = write_twin(canonical, tmp_path / "bluerov2_ned", "odometry_ned")
    arts = _engine(twin, tmp_path / "store")
    sensors = json.loads((arts["keyframes"] / "sensors.json").read_text())
    assert any("NED (world) and FRD (body)" in w for w in sensors["source"]["warnings"])
    dz, iou = _compare(canonical, arts, align=False)
    assert dz <= 0.05 and iou >= 0.95, (dz, iou)


def test_dvl_imu_pressure_twin_in_mounted_frames_maps_the_same_world(
    canonical: Canonical, tmp_path: Path
) -> None:
    twin = write_twin(canonical, tmp_path / "bluerov2_dvl", "dvl")
    arts = _engine(twin, tmp_path / "store")
    dz, iou = _compare(canonical, arts, align=True)
    assert dz <= 0.10 and iou >= 0.8, (dz, iou)
    prov = json.loads((arts["keyframes"] / "sensors.json").read_text())["provenance"]
    assert prov["dvl"]["frame"] == "dvl_link" and prov["dvl"]["mount_xyz"] == "recording"
    assert prov["imu"]["frame"] == "imu_link" and prov["imu"]["mount_rpy"] == "recording"
    assert prov["depth"]["topic"] == "/bar30/pressure"
    assert prov["depth"]["surface_pressure"] == "default"
    assert prov["dvl"]["dropped"] == {}


def write_polar_twin(canonical: Canonical, out: Path, keep: np.ndarray) -> Path:
    """The canonical mission with both sonars as polar `sensor_msgs/Image`s (mono8, as
    a driver publishes them), keeping the image columns `keep`: the same pings, with an
    uneven beam table (the angles of the kept columns), and everything else as recorded."""
    from mcap.reader import make_reader

    from sonarmap.pipeline.readers import open_recording

    store = ros2_types()
    t = store.types
    rec = open_recording(canonical.path)
    sonar_topics = {"/sonar/horizontal": "horizontal", "/sonar/vertical": "vertical"}
    events: list[tuple[int, str, str, Any]] = []
    with canonical.path.open("rb") as f:
        for schema, channel, m in make_reader(f).iter_messages():
            if channel.topic in sonar_topics or channel.topic.startswith("/sonar/"):
                continue  # the sonars (and their label / truth images) are re-encoded below
            events.append(
                (m.log_time, channel.topic, schema.name, store.deserialize_cdr(m.data, schema.name))
            )
    for topic, sonar in sonar_topics.items():
        times = rec.ping_times_ns(sonar)
        for t_ns, ping in zip(
            times, rec.pings(sonar, np.arange(len(times)), labels=False), strict=True
        ):
            image = np.ascontiguousarray(ping.image[:, keep])
            msg = t["sensor_msgs/msg/Image"](
                header=ros_header(t, int(t_ns), f"sonar_{sonar}"),
                height=image.shape[0],
                width=image.shape[1],
                encoding="mono8",
                is_bigendian=0,
                step=image.shape[1],
                data=image.reshape(-1),
            )
            events.append((int(t_ns), topic, "sensor_msgs/msg/Image", msg))
    return write_bag(out, store, events)


def test_polar_image_twin_with_an_uneven_beam_table_file_maps_the_same_world(
    canonical: Canonical, tmp_path: Path
) -> None:
    angles = canonical.run.frame(0).horizontal.angles_rad.astype(np.float64)
    # Uneven like a real sonar's table: every beam within 30 deg of the axis, every
    # other one beyond (spacing 0.25 deg in the centre, 0.51 deg at the edges).
    index = np.arange(len(angles))
    keep = index[(np.abs(np.rad2deg(angles)) <= 30.0) | (index % 2 == 0)]
    table = tmp_path / "beams.csv"
    table.write_text("\n".join(f"{np.rad2deg(a):.9f}" for a in angles[keep]) + "\n")
    twin = write_polar_twin(canonical, tmp_path / "polar_twin", keep)
    # An Image topic could be a camera: the polar sonar images are named, with their table.
    overrides = (
        "keyframes.horizontal_topic=/sonar/horizontal",
        "keyframes.vertical_topic=/sonar/vertical",
        f"keyframes.horizontal_sonar={table}",
        f"keyframes.vertical_sonar={table}",
    )
    arts = _engine(twin, tmp_path / "store", overrides)
    sensors = json.loads((arts["keyframes"] / "sensors.json").read_text())
    spacing = np.diff(np.rad2deg(angles[keep]))
    assert spacing.max() > 1.9 * spacing.min()  # the table really is uneven
    assert sensors["horizontal"]["fov_deg"] == pytest.approx(
        np.rad2deg(np.ptp(angles[keep])), abs=1.0
    )
    dz, iou = _compare(canonical, arts, align=False)
    assert dz <= 0.10 and iou >= 0.8, (dz, iou)
    # Read as evenly spaced beams (the table left out), the same images map elsewhere.
    even = _engine(twin, tmp_path / "even", overrides[:2])
    even_iou = _compare(canonical, even, align=False)[1]
    assert even_iou < iou - 0.1


def test_compressed_grey_colour_sonar_images_keep_their_labels_aligned(
    canonical: Canonical, tmp_path: Path
) -> None:
    # Compressed transport carries no width in the message: the label images beside it
    # were ordered by it and came out 0 columns wide (classify then failed, exit 1).
    import io

    from mcap.reader import make_reader
    from PIL import Image

    from sonarmap.pipeline.readers import open_recording

    store = ros2_types()
    t = store.types
    rec = open_recording(canonical.path)
    events: list[tuple[int, str, str, Any]] = []
    with canonical.path.open("rb") as f:
        for schema, channel, m in make_reader(f).iter_messages():
            if not channel.topic.startswith("/sonar/"):
                msg = store.deserialize_cdr(m.data, schema.name)
                events.append((m.log_time, channel.topic, schema.name, msg))
    written = {}
    for sonar in ("horizontal", "vertical"):
        times = rec.ping_times_ns(sonar)
        pings = list(rec.pings(sonar, np.arange(len(times)), labels=True))
        written[sonar] = pings[:3]
        for t_ns, ping in zip(times, pings, strict=True):
            png = io.BytesIO()
            Image.fromarray(np.repeat(ping.image[..., None], 3, axis=2)).save(png, "PNG")
            header = ros_header(t, int(t_ns), f"sonar_{sonar}")
            data = np.frombuffer(png.getvalue(), np.uint8)
            image = t["sensor_msgs/msg/CompressedImage"](header=header, format="png", data=data)
            events.append((int(t_ns), f"/sonar/{sonar}", image.__msgtype__, image))
            h, w = ping.labels.shape
            labels = t["sensor_msgs/msg/Image"](
                header=header,
                height=h,
                width=w,
                encoding="mono8",
                is_bigendian=0,
                step=w,
                data=ping.labels.reshape(-1),
            )
            events.append((int(t_ns), f"/sonar/{sonar}/labels", labels.__msgtype__, labels))
    twin = write_bag(tmp_path / "compressed", store, events)
    topics = {"horizontal_topic": "/sonar/horizontal", "vertical_topic": "/sonar/vertical"}
    read = open_recording(twin, topics)
    for sonar, pings in written.items():
        got = read.pings(sonar, np.arange(len(pings)), labels=True)
        for ping, back in zip(pings, got, strict=True):
            # An RGB image with equal channels is its grey level; column 0 is port, as a
            # polar image's, so both the image and its labels come back mirrored.
            assert np.array_equal(back.image, ping.image[:, ::-1])
            assert back.labels is not None and np.array_equal(back.labels, ping.labels[:, ::-1])
