"""Write a simulated mission (`sonarmap.sim.dataset.SimRun`) as a ROS 2 MCAP dataset.

Topics (schemas/topics.py): ProjectedSonarImage per sonar, mono8 label images, 32FC1
truth-angle images, dead-reckoning and ground-truth Odometry, /tf_static with both
sonar mountings. Attachments: `scene.ply` (ground-truth mesh with per-vertex object and
class ids) and `scene.yaml`. Metadata record "sonarmap": simulator version, seed, scene
name and the full simulator config as JSON strings. Log times are the ping times, so the
same (scene, config, seed) gives the same bytes. The file is written to a temporary
name next to `path` and renamed into place.
"""

from __future__ import annotations

import json
import struct
import time
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.formats.atomic import atomic_output
from sonarmap.pipeline.formats.frames_io import image_message
from sonarmap.pipeline.formats.rosmsg import recording_writer, ros2_typestore
from sonarmap.pipeline.formats.sim_render import rendered_frames
from sonarmap.schemas.sonar import SonarPing, beam_directions_from_angles
from sonarmap.schemas.topics import (
    FRAME_BASE,
    FRAME_ODOM,
    FRAME_SONAR,
    IMAGE_TYPE,
    LABEL_TOPIC,
    ODOMETRY_TYPE,
    PROJECTED_SONAR_TYPE,
    SONAR_TOPIC,
    SONARS,
    TOPIC_DEAD_RECKONING,
    TOPIC_GROUND_TRUTH,
    TOPIC_TF_STATIC,
    TRUTH_ANGLE_TOPIC,
)
from sonarmap.sim.dataset import SIM_VERSION, SimRun
from sonarmap.stages.kernels.geometry import matrix_from_rpy_product, quat_from_matrix

__all__ = ["TF_TYPE", "write_simulation"]

TF_TYPE = "tf2_msgs/msg/TFMessage"


class _Messages:
    """Builds rosbags message objects; per-sonar constant parts are built once."""

    def __init__(self, run: SimRun) -> None:
        self.t = ros2_typestore().types
        self._static: dict[str, tuple[Any, list[Any], np.ndarray]] = {}
        for s in SONARS:
            cfg = run.config.sonar(s)
            dirs = beam_directions_from_angles(cfg.angles_rad())
            vec = [self.t["geometry_msgs/msg/Vector3"](x=d[0], y=d[1], z=d[2]) for d in dirs]
            # tx: the aperture (unresolved direction); rx: the -3 dB width across the fan.
            bw = np.full(cfg.n_beams, np.deg2rad(cfg.beam_width_deg), np.float32)
            info = self.t["marine_acoustic_msgs/msg/PingInfo"](
                frequency=float(cfg.frequency_hz),
                sound_speed=float(cfg.sound_speed_m_s),
                tx_beamwidths=np.full(cfg.n_beams, np.deg2rad(cfg.aperture_deg), np.float32),
                rx_beamwidths=bw,
            )
            self._static[s] = (info, vec, cfg.ranges_m().astype(np.float32))

    def header(self, t_ns: int, frame: str) -> Any:
        stamp = self.t["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        return self.t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def sonar(self, ping: SonarPing) -> Any:
        info, vec, ranges = self._static[ping.sonar]
        img = self.t["marine_acoustic_msgs/msg/SonarImageData"](
            is_bigendian=False,
            dtype=0,
            beam_count=ping.image.shape[1],
            data=np.ascontiguousarray(ping.image, dtype=np.uint8).reshape(-1),
        )
        return self.t[PROJECTED_SONAR_TYPE](
            header=self.header(ping.t_ns, FRAME_SONAR[ping.sonar]),
            ping_info=info,
            beam_directions=vec,
            ranges=ranges,
            image=img,
        )

    def odometry(self, t_ns: int, pose: np.ndarray, vel_b: np.ndarray, sigma: float) -> Any:
        q = quat_from_matrix(matrix_from_rpy_product(pose[3:6]))
        return self.odometry_raw(t_ns, np.concatenate([pose[:3], q, vel_b[:2]]), sigma)

    def odometry_raw(self, t_ns: int, v: np.ndarray, sigma: float) -> Any:
        """Odometry from (x, y, z, qx, qy, qz, qw, vx_body, vy_body)."""
        t = self.t
        pose, q, vel_b = v[:3], v[3:7], v[7:9]
        p = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=pose[0], y=pose[1], z=pose[2]),
            orientation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        cov = np.diag(np.full(6, sigma**2)).reshape(-1)
        zero = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        tw = t["geometry_msgs/msg/Twist"](
            linear=t["geometry_msgs/msg/Vector3"](x=vel_b[0], y=vel_b[1], z=0.0), angular=zero
        )
        return t[ODOMETRY_TYPE](
            header=self.header(t_ns, FRAME_ODOM),
            child_frame_id=FRAME_BASE,
            pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=p, covariance=cov),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=tw, covariance=cov.copy()),
        )

    def tf_static(self, t_ns: int, mounts: dict[str, np.ndarray]) -> Any:
        t = self.t
        tfs = []
        for s in SONARS:
            m = mounts[s]
            q = quat_from_matrix(m[:3, :3])
            tr = t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=m[0, 3], y=m[1, 3], z=m[2, 3]),
                rotation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            )
            tfs.append(
                t["geometry_msgs/msg/TransformStamped"](
                    header=self.header(t_ns, FRAME_BASE),
                    child_frame_id=FRAME_SONAR[s],
                    transform=tr,
                )
            )
        return t[TF_TYPE](transforms=tfs)


class _TemplateCdr:
    """CDR bytes of one topic's messages from a serialised template.

    Per message only header.stamp (payload offset 0: int32 sec, uint32 nanosec), an
    optional trailing uint8[] payload of fixed length and optional float64 fields change;
    float64 slots are located once by serialising unique sentinel values. Equality with
    rosbags' `serialize_cdr` is checked in tests/test_sim_mcap.py.
    """

    _STAMP = struct.Struct("<iI")

    def __init__(self, typename: str, message: Any, data_len: int = 0, slots: int = 0) -> None:
        cdr = bytes(ros2_typestore().serialize_cdr(message, typename))
        self._prefix = bytearray(cdr[: len(cdr) - data_len])
        self._offsets = np.array(
            [self._prefix.find(struct.pack("<d", _sentinel(k))) for k in range(slots)], np.int64
        )
        if np.any(self._offsets < 0):
            raise RuntimeError(f"CDR template for {typename}: sentinel not found")

    def encode(self, t_ns: int, data: bytes = b"", values: np.ndarray | None = None) -> bytes:
        self._STAMP.pack_into(self._prefix, 4, t_ns // 10**9, t_ns % 10**9)
        if values is not None:
            for off, v in zip(self._offsets.tolist(), values.tolist(), strict=True):
                struct.pack_into("<d", self._prefix, off, v)
        return bytes(self._prefix) + data


def _sentinel(k: int) -> float:
    return 1.2345678901234567e17 + 4096.0 * k


class _FastEncoder:
    """Template-based CDR for every per-frame topic of a simulated run."""

    def __init__(self, run: SimRun, build: _Messages, sigma_dr: float) -> None:
        self.tpl: dict[str, _TemplateCdr] = {}
        for s in SONARS:
            cfg = run.config.sonar(s)
            shape = (cfg.n_ranges, cfg.n_beams)
            ping = SonarPing(0, s, np.zeros(shape, np.uint8), cfg.ranges_m(), cfg.angles_rad())
            size = shape[0] * shape[1]
            self.tpl[SONAR_TOPIC[s]] = _TemplateCdr(PROJECTED_SONAR_TYPE, build.sonar(ping), size)
            lab = image_message(np.zeros(shape, np.uint8), 0, FRAME_SONAR[s])
            self.tpl[LABEL_TOPIC[s]] = _TemplateCdr(IMAGE_TYPE, lab, size)
            ang = image_message(np.zeros(shape, np.float32), 0, FRAME_SONAR[s])
            self.tpl[TRUTH_ANGLE_TOPIC[s]] = _TemplateCdr(IMAGE_TYPE, ang, 4 * size)
        for topic, sigma in ((TOPIC_DEAD_RECKONING, sigma_dr), (TOPIC_GROUND_TRUTH, 0.0)):
            msg = build.odometry_raw(0, np.array([_sentinel(k) for k in range(9)]), sigma)
            self.tpl[topic] = _TemplateCdr(ODOMETRY_TYPE, msg, 0, slots=9)

    def image(self, topic: str, t_ns: int, arr: np.ndarray) -> bytes:
        return self.tpl[topic].encode(t_ns, np.ascontiguousarray(arr).tobytes())

    def odometry(self, topic: str, t_ns: int, pose: np.ndarray, vel_b: np.ndarray) -> bytes:
        q = quat_from_matrix(matrix_from_rpy_product(pose[3:6]))
        values = np.concatenate([pose[:3], q, vel_b[:2]])
        return self.tpl[topic].encode(t_ns, b"", values)


def _body_velocity(t_ns: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """(n, 2) body-frame planar velocity [m/s] by forward differences (last repeats)."""
    n = len(t_ns)
    v = np.zeros((n, 2))
    if n > 1:
        dt = np.diff(t_ns).astype(np.float64) / 1e9
        v[:-1] = np.diff(pose[:, :2], axis=0) / dt[:, None]
        v[-1] = v[-2]
    c, s = np.cos(pose[:, 5]), np.sin(pose[:, 5])
    return np.stack([c * v[:, 0] + s * v[:, 1], -s * v[:, 0] + c * v[:, 1]], axis=1)


def simulation_metadata(run: SimRun) -> dict[str, str]:
    """The "sonarmap" metadata record: string -> string."""
    return {
        "generator": "sonarmap.sim",
        "simulator_version": SIM_VERSION,
        "seed": str(run.seed),
        "scene": run.world.scene.name,
        "n_frames": str(run.n_frames),
        # Neutral image-character settings are left out: clean recordings keep their bytes.
        "config": run.config.model_dump_json(exclude=run.config.unrecorded()),  # type: ignore[arg-type]
        "sonars": json.dumps(
            {
                s: run.config.sonar(s).model_dump(
                    mode="json", exclude=run.config.sonar(s).unrecorded()
                )
                for s in SONARS
            }
        ),
        "navigation_noise": run.config.navigation.model_dump_json(),
        "mission": run.config.mission.model_dump_json(),
        "has_ground_truth": "true",
        "has_labels": "true",
    }


def write_simulation(
    run: SimRun,
    path: Path,
    *,
    scene_yaml: str,
    progress: Callable[[int, int], None] | None = None,
    workers: int = 1,
) -> dict[str, Any]:
    """Render every frame of `run` and write the MCAP atomically.

    Args:
        run: the simulated mission.
        path: output .mcap path (missing parent directories are created).
        scene_yaml: text of the scene file, stored as the `scene.yaml` attachment.
        progress: optional callback (frames_done, n_frames).
        workers: processes rendering frames ahead of the writer (1 = serial, in this
            process; `sonarmap.pipeline.formats.sim_render`); the bytes do not depend on it.

    Returns:
        {"path", "n_frames", "bytes", "seconds", "frames_per_s", "messages"}.

    Raises:
        SourceError: the output directory cannot be created or written.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise SourceError(f"cannot create output directory {path.parent}: {err}") from err
    t0 = time.perf_counter()
    build = _Messages(run)
    traj = run.trajectory
    t_ns_all = traj["t_ns"]
    v_gt = _body_velocity(t_ns_all, traj["gt_pose"])
    v_dr = _body_velocity(t_ns_all, traj["dr_pose"])
    sigma_dr = max(run.config.navigation.dvl_noise_m_s, 1e-3)
    t_first = int(t_ns_all[0])
    fast = _FastEncoder(run, build, sigma_dr)
    n_msgs = 0
    with ExitStack() as stack:
        try:
            f = stack.enter_context(atomic_output(path))
        except OSError as err:
            raise SourceError(f"cannot write to {path.parent}: {err}") from err
        with recording_writer(f) as w:
            w.write(TOPIC_TF_STATIC, TF_TYPE, build.tf_static(t_first, run.T_base_sonar), t_first)
            n_msgs += 1
            for frame in rendered_frames(run, workers):
                t, i = frame.t_ns, frame.index
                for ping in (frame.horizontal, frame.vertical):
                    s = ping.sonar
                    assert ping.labels is not None and ping.truth_angle_rad is not None
                    truth = ping.truth_angle_rad.astype(np.float32)
                    for topic, typename, arr in (
                        (SONAR_TOPIC[s], PROJECTED_SONAR_TYPE, ping.image),
                        (LABEL_TOPIC[s], IMAGE_TYPE, ping.labels),
                        (TRUTH_ANGLE_TOPIC[s], IMAGE_TYPE, truth),
                    ):
                        w.write_raw(topic, typename, fast.image(topic, t, arr), t)
                for topic, pose, vel in (
                    (TOPIC_DEAD_RECKONING, frame.dr_pose, v_dr[i]),
                    (TOPIC_GROUND_TRUTH, frame.gt_pose, v_gt[i]),
                ):
                    w.write_raw(topic, ODOMETRY_TYPE, fast.odometry(topic, t, pose, vel), t)
                n_msgs += 8
                if progress is not None:
                    progress(i + 1, run.n_frames)
            w.add_attachment("scene.ply", run.world.to_ply_bytes(), "application/x-ply", t_first)
            w.add_attachment("scene.yaml", scene_yaml.encode(), "application/yaml", t_first)
            w.add_metadata("sonarmap", simulation_metadata(run))
    seconds = time.perf_counter() - t0
    return {
        "path": str(path),
        "n_frames": run.n_frames,
        "bytes": path.stat().st_size,
        "seconds": seconds,
        "frames_per_s": run.n_frames / seconds if seconds > 0 else float("inf"),
        "messages": n_msgs,
    }
