"""Small synthetic recordings for the ingestion tests and the QA campaign's ingest cases.

`write_recording` writes both sonars (ProjectedSonarImage, raw CDR) and dead-reckoning
odometry, with hooks that make one field hostile: ranges, beam directions, image size,
timestamps, navigation positions and quaternions.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from sonarmap.pipeline.formats.projected_cdr import serialize_projected_cdr
from sonarmap.pipeline.formats.rosmsg import Ros2McapWriter, recording_writer, ros2_typestore
from sonarmap.schemas.sonar import beam_directions_from_angles
from sonarmap.schemas.topics import (
    ODOMETRY_TYPE,
    PROJECTED_SONAR_TYPE,
    SONAR_TOPIC,
    TOPIC_DEAD_RECKONING,
)

T0 = 1_700_000_000_000_000_000
NavHook = Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def odometry(t_ns: int, xyz: np.ndarray, q_xyzw: np.ndarray) -> Any:
    """A nav_msgs Odometry with any position and quaternion values (NaN and zero too)."""
    t = ros2_typestore().types
    header = t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9),
        frame_id="odom",
    )
    x, y, z = (float(v) for v in xyz)
    qx, qy, qz, qw = (float(v) for v in q_xyzw)
    pose = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=x, y=y, z=z),
        orientation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
    )
    zero = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    return t[ODOMETRY_TYPE](
        header=header,
        child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)
        ),
    )


def write_recording(
    path: Path,
    *,
    n_pings: int = 40,
    rate_hz: float = 2.0,
    n_ranges: int = 64,
    n_beams: int = 32,
    ranges: np.ndarray | None = None,
    directions: np.ndarray | None = None,
    bad_pings: Callable[[int], bool] = lambda k: True,
    same_time: bool = False,
    nav: NavHook | None = None,
    layout: str = "recording",
    chunk_bytes: int = 256 * 1024,
    nav_offset_ns: int = 0,
) -> dict[str, Any]:
    """Write a synthetic recording; returns its ping and navigation times.

    Args:
        ranges, directions: replace the ping's ranges / beam directions (for the pings
            where `bad_pings(k)` is True; the others keep the sane ones).
        same_time: every sonar message gets the first ping's time.
        nav: (t_ns, xyz, q_xyzw) -> (xyz, q_xyzw) applied to the navigation samples.
        nav_offset_ns: added to the navigation times (moves them away from the pings).
        layout: "recording" (sonarmap's own writer) or "interleaved" (a recorder's: one
            chunk stream in time order, chunks of `chunk_bytes`).
    """
    angles = np.deg2rad(np.linspace(-30, 30, n_beams))
    good_dirs = beam_directions_from_angles(angles)
    good_ranges = ((np.arange(n_ranges) + 0.5) * 0.25).astype(np.float32)
    rng = np.random.default_rng(0)
    ping_t = T0 + (np.arange(n_pings) * (1e9 / rate_hz)).astype(np.int64)
    nav_t = T0 - 500_000_000 + (np.arange(int(n_pings / rate_hz * 10) + 10) * 1e8).astype(np.int64)
    s = (nav_t - T0) * 1e-9
    xyz = np.column_stack([0.5 * s, np.zeros_like(s), np.full_like(s, -2.0)])
    q = np.tile([0.0, 0.0, 0.0, 1.0], (len(s), 1))
    if nav is not None:
        xyz, q = nav(nav_t, xyz, q)
    nav_t = nav_t + nav_offset_ns
    events: list[tuple[int, int, str, str, Any]] = []
    for k, t in enumerate(ping_t.tolist()):
        r = ranges if ranges is not None and bad_pings(k) else good_ranges
        d = directions if directions is not None and bad_pings(k) else good_dirs
        # Mostly dark with sparse echoes: compresses like a sonar image.
        image = (rng.random((len(r), len(d))) < 0.02).astype(np.uint8) * 200
        for sonar, dt in (("horizontal", 0), ("vertical", 3_000_000)):
            tm = ping_t[0] if same_time else t + dt
            cdr = serialize_projected_cdr(int(tm), "sonar", d, r, image)
            events.append(
                (int(tm), 0 if sonar == "horizontal" else 1, SONAR_TOPIC[sonar], "raw", cdr)
            )
    for t, p, o in zip(nav_t.tolist(), xyz, q, strict=True):
        events.append((t, 2, TOPIC_DEAD_RECKONING, ODOMETRY_TYPE, odometry(t, p, o)))
    events.sort(key=lambda e: (e[0], e[1]))
    with path.open("wb") as f:
        writer = (
            recording_writer(f)
            if layout == "recording"
            else Ros2McapWriter(f, chunk_size=chunk_bytes)
        )
        with writer as w:
            for t, _, topic, typ, msg in events:
                if typ == "raw":
                    w.write_raw(topic, PROJECTED_SONAR_TYPE, msg, t)
                else:
                    w.write(topic, typ, msg, t)
    return {"ping_t": ping_t, "nav_t": nav_t}
