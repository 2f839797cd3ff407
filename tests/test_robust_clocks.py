"""Field clocks and trees (issue 52, root 5): clocks that run backwards or jump, time
conversions that overflow, a frame with two parents, NaN IMU rates, a DVL with one time;
and `convert` printing the reader's warnings as `topics` does."""

from __future__ import annotations

import logging
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_readers_mcap import T0, odom_msg, sonar_msg
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.formats.rosmsg import Ros2McapWriter, ros2_typestore
from sonarmap.pipeline.readers import open_recording, open_source
from sonarmap.pipeline.readers.aris_layout import FRAME_HEADER
from sonarmap.pipeline.readers.clock import backwards, gap_warning
from sonarmap.schemas.topics import ODOMETRY_TYPE, PROJECTED_SONAR_TYPE, SONAR_TOPIC

S = 1_000_000_000
ANGLES = np.deg2rad(np.linspace(-30, 30, 24))
NAV = "/odometry/dead_reckoning"


def _vec(t: Any, v: Any) -> Any:
    return t["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _header(t: Any, t_ns: int, frame: str) -> Any:
    stamp = t["builtin_interfaces/msg/Time"](sec=t_ns // S, nanosec=t_ns % S)
    return t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def _pings(n: int = 20, every_s: float = 1.0) -> list[tuple[int, str, str, Any]]:
    out = []
    for k in range(n):
        t = T0 + int(k * every_s * S)
        for s in ("horizontal", "vertical"):
            out.append(
                (
                    t + (s == "vertical"),
                    SONAR_TOPIC[s],
                    PROJECTED_SONAR_TYPE,
                    sonar_msg(t, k, ANGLES),
                )
            )
    return out


def _write(path: Path, events: list[tuple[int, str, str, Any]], chunk: int = 1 << 20) -> Path:
    """Events written in the order given (not sorted): a recorder's file order."""
    with path.open("wb") as f, Ros2McapWriter(f, chunk_size=chunk) as w:
        for t, topic, typ, msg in events:
            w.write(topic, typ, msg, t)
    return path


def _nav(times_s: list[float], speed: float = 0.5) -> list[tuple[int, str, str, Any]]:
    return [
        (T0 + int(s * S), NAV, ODOMETRY_TYPE, odom_msg(T0 + int(s * S), speed * s, 0.0, 0.0, 0.0))
        for s in times_s
    ]


def test_backwards_and_gap_helpers() -> None:
    assert backwards(np.array([0, 1, 2, 3]) * S) is None
    # Jitter within the tolerance is sorted, not dropped.
    assert backwards(np.array([0, 10, 5, 20]) * 1_000_000) is None
    found = backwards(np.array([0, 1, 2, 3, 1, 2, 4]) * S)
    assert found is not None and found.behind.tolist() == [0, 0, 0, 0, 1, 1, 0]
    assert found.first_t_ns == S and found.back_ns == 2 * S
    assert gap_warning("x", np.arange(10) * S, "a pose") is None
    line = gap_warning("x: /nav", np.r_[np.arange(10), 3600 + np.arange(10)] * S, "a pose")
    assert line and "x: /nav: the clock jumps forward 1 time(s)" in line and "3591 s" in line


@pytest.mark.parametrize("chunk", [1 << 20, 600], ids=["one-chunk", "many-chunks"])
def test_navigation_clock_set_back_is_dropped_with_a_warning(
    tmp_path: Path, chunk: int, caplog: pytest.LogCaptureFixture
) -> None:
    # 0..12 s, then the clock is set back 8 s: 4.1..12 s again (at other places).
    first = [k * 0.1 for k in range(121)]
    again = [4.1 + k * 0.1 for k in range(60)]
    nav = _nav(first) + [
        (t, tp, ty, odom_msg(t, 100.0, 5.0, 0.0, 1.0)) for t, tp, ty, _ in _nav(again)
    ]
    path = _write(tmp_path / "d.mcap", _pings(12) + nav, chunk)
    with caplog.at_level(logging.WARNING):
        rec = open_recording(path)
        track = rec.navigation()
    lines = [w for w in rec.source.warnings if "runs backwards" in w]
    assert len(lines) == 1, rec.source.warnings
    assert f"{NAV}: the clock runs backwards: dropped 60 of 181 messages" in lines[0]
    assert "7.9 s back" in lines[0]
    assert len(track) == 121 and np.all(np.diff(track.t_ns) > 0)
    assert float(np.abs(track.xyz_m[:, 0] - 0.5 * (track.t_ns - T0) * 1e-9).max()) < 1e-9


def test_forward_jump_in_the_navigation_is_warned(tmp_path: Path) -> None:
    nav = _nav([k * 0.1 for k in range(50)] + [3600 + k * 0.1 for k in range(50)], speed=0.0)
    rec = open_recording(_write(tmp_path / "d.mcap", _pings(5) + nav))
    rec.navigation()
    [line] = [w for w in rec.source.warnings if "jumps forward" in w]
    assert NAV in line and "1 time(s)" in line


def _tf(t: Any, parent: str, child: str, xyz: tuple[float, float, float]) -> Any:
    return t["geometry_msgs/msg/TransformStamped"](
        header=_header(t, T0, parent),
        child_frame_id=child,
        transform=t["geometry_msgs/msg/Transform"](
            translation=_vec(t, xyz),
            rotation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
    )


def test_a_frame_with_two_parents_is_refused_naming_both(tmp_path: Path) -> None:
    t = ros2_typestore().types
    tfs = [
        _tf(t, "base_link", "mount", (0.0, 0, 0)),
        _tf(t, "base_link", "sonar", (0.5, 0, 0)),
        _tf(t, "mount", "sonar", (5.0, 0, 0)),
    ]
    msg = t["tf2_msgs/msg/TFMessage"](transforms=tfs)
    events = [(T0, "/tf_static", "tf2_msgs/msg/TFMessage", msg), *_pings(5), *_nav([0, 1, 2, 3])]
    rec = open_recording(_write(tmp_path / "d.mcap", events))
    with pytest.raises(
        SourceError,
        match=r"/tf_static: frame 'sonar' has two parents, "
        r"'base_link' and 'mount'",
    ):
        rec.mountings()


def _dvl_imu(
    times_s: list[float], imu_rate: Any = (0.0, 0.0, 0.0), dvl_times_s: list[float] | None = None
) -> list[tuple[int, str, str, Any]]:
    t = ros2_typestore().types
    out = []
    for k, s in enumerate(times_s):
        tn = T0 + int(s * S)
        w = imu_rate(k) if callable(imu_rate) else imu_rate
        imu = t["sensor_msgs/msg/Imu"](
            header=_header(t, tn, "base_link"),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.zeros(9),
            angular_velocity=_vec(t, w),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=_vec(t, (0.0, 0.0, 9.81)),
            linear_acceleration_covariance=np.zeros(9),
        )
        out.append((tn, "/imu/data", "sensor_msgs/msg/Imu", imu))
    for s in times_s if dvl_times_s is None else dvl_times_s:
        tn = T0 + int(s * S)
        twist = t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](
                linear=_vec(t, (0.5, 0.0, 0.0)), angular=_vec(t, (0.0, 0.0, 0.0))
            ),
            covariance=np.zeros(36),
        )
        msg = t["geometry_msgs/msg/TwistWithCovarianceStamped"](
            header=_header(t, tn, "base_link"), twist=twist
        )
        out.append((tn, "/dvl/twist", "geometry_msgs/msg/TwistWithCovarianceStamped", msg))
    return sorted(out, key=lambda e: e[0])


def test_nan_imu_rates_are_dropped_and_counted(tmp_path: Path) -> None:
    times = [k * 0.2 for k in range(50)]
    nan = float("nan")
    events = _pings(10) + _dvl_imu(times, lambda k: (nan, 0.0, 0.0) if k % 5 == 2 else (0, 0, 0))
    rec = open_recording(_write(tmp_path / "d.mcap", events))
    track = rec.navigation()
    [line] = [w for w in rec.source.warnings if "/imu/data" in w and "dropped" in w]
    assert "dropped 10 of 50 samples" in line
    assert np.all(np.isfinite(track.xyz_m))


@pytest.mark.parametrize("dvl", [[3.0], [3.0, 3.0, 3.0]], ids=["one", "one-time"])
def test_a_dvl_with_one_time_names_the_dvl_topic(tmp_path: Path, dvl: list[float]) -> None:
    events = _pings(10) + _dvl_imu([k * 0.2 for k in range(50)], dvl_times_s=dvl)
    rec = open_recording(_write(tmp_path / "d.mcap", events))
    with pytest.raises(SourceError, match=r"/dvl/twist: the DVL has \d usable sample\(s\) at 1 "):
        rec.navigation()


def _aris(shared_data: Path, tmp_path: Path, edit: Any) -> Path:
    buf = bytearray((shared_data / "aris" / "sample.aris").read_bytes())
    edit(buf)
    out = tmp_path / "dive.aris"
    out.write_bytes(bytes(buf))
    return out


FRAME_BYTES = 1024 + 48 * 2000
TIME_AT = FRAME_HEADER.fields["FrameTime"][1]


@pytest.mark.parametrize("us", [2**62, 2**64 - 1])
def test_aris_frame_time_past_int64_ns_is_refused(
    shared_data: Path, tmp_path: Path, us: int
) -> None:
    path = _aris(
        shared_data,
        tmp_path,
        lambda b: struct.pack_into("<Q", b, 1024 + 2 * FRAME_BYTES + TIME_AT, us),
    )
    with pytest.raises(SourceError, match=rf"dive\.aris: frame 2 .*FrameTime {us} us is past"):
        open_source(path)
    res = CliRunner().invoke(app, ["convert", str(path), "-o", str(tmp_path / "o.mcap")])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert not (tmp_path / "o.mcap").exists()


def test_aris_clock_set_back_drops_frames(shared_data: Path, tmp_path: Path) -> None:
    def edit(b: bytearray) -> None:
        (t2,) = struct.unpack_from("<Q", b, 1024 + 2 * FRAME_BYTES + TIME_AT)
        struct.pack_into("<Q", b, 1024 + 4 * FRAME_BYTES + TIME_AT, t2 - 5_000_000)

    src = open_source(_aris(shared_data, tmp_path, edit))
    assert src.topics()[0].count == 5
    assert any("runs backwards: dropped 1 of 6 frames" in w for w in src.warnings)


def test_convert_prints_the_aris_warnings_topics_prints(shared_data: Path, tmp_path: Path) -> None:
    lens_at = FRAME_HEADER.fields["LargeLens"][1]
    path = _aris(
        shared_data,
        tmp_path,
        lambda b: [
            struct.pack_into(
                "<B" if FRAME_HEADER.fields["LargeLens"][0].itemsize == 1 else "<I",
                b,
                1024 + k * FRAME_BYTES + lens_at,
                1,
            )
            for k in range(6)
        ],
    )
    topics = CliRunner().invoke(app, ["topics", str(path)])
    assert topics.exit_code == 0 and "telephoto" in topics.output
    res = CliRunner().invoke(app, ["convert", str(path), "-o", str(tmp_path / "o.mcap")])
    assert res.exit_code == 0, res.output
    warned = [ln for ln in res.output.splitlines() if ln.startswith("warning:")]
    assert any("telephoto lens" in ln for ln in warned), res.output
