"""Field recordings as vehicles publish them (issue 37 items 1, 2, 5): a recording is
mapped right, refused with one line naming what is missing (and the candidates), or
mapped with a warning saying what was substituted or dropped and how much.

Each case writes a small rosbag2 (blank pings on the drivers' topics, DVL + IMU + Bar30
or a pose navigation, a tf chain) with `tests.fixtures.write_navigation_bag` and
runs `sonarmap run BAG --until keyframes`.
"""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tests.contract.case import Case, names

Edit = Callable[[list[Any]], list[Any]]


def _bag(
    workdir: Path,
    *sets: str,
    edit: Edit | None = None,
    tf: bool = True,
    navigation: str = "dvl",
    speed: float = 0.5,
) -> list[str]:
    from tests.fixtures import navigation_mission, write_navigation_bag  # rosbags, scipy: lazily

    bag = write_navigation_bag(
        workdir / "dive", navigation_mission(speed, 20.0), navigation=navigation, tf=tf, edit=edit
    )
    args = ["run", str(bag), "--until", "keyframes", "--store", "data/store", "-q"]
    for s in sets:
        args += ["--set", s]
    return args


def _topic(events: list[Any], name: str) -> list[Any]:
    return [e for e in events if e[1] == name]


def _dvl(edit: Callable[[Any, int], None]) -> Edit:
    def apply(events: list[Any]) -> list[Any]:
        for k, e in enumerate(_topic(events, "/dvl/twist")):
            edit(e[3].twist.twist.linear, k)
        return events

    return apply


def _pressure(scale: float) -> Edit:
    def apply(events: list[Any]) -> list[Any]:
        for e in _topic(events, "/bar30/pressure"):
            e[3].fluid_pressure *= scale
        return events

    return apply


def _drop(topic: str) -> Edit:
    return lambda events: [e for e in events if e[1] != topic]


def _twice_pressure(events: list[Any]) -> list[Any]:
    return events + [
        (t, "/mavros/imu/static_pressure", typ, msg)
        for t, _, typ, msg in _topic(events, "/bar30/pressure")
    ]


def _changing_tf(events: list[Any]) -> list[Any]:
    from tests.fixtures import mount_matrix, ros2_types, tf_stamped

    # The DVL's frame is on /tf only (not /tf_static), and its transform turns.
    t = ros2_types().types
    out = list(events)
    for e in _topic(events, "/dvl/twist"):
        e[3].header.frame_id = "dvl_head"
    for k, e in enumerate(_topic(events, "/mavros/imu/data")[:20]):
        T = mount_matrix((180.0, 0.0, 45.0 + 2.0 * k), (-0.2, 0.1, -0.15))
        tf = tf_stamped(t, e[0], "base_link", "dvl_head", T)
        msg = t["tf2_msgs/msg/TFMessage"](transforms=[tf])
        out.append((e[0], "/tf", "tf2_msgs/msg/TFMessage", msg))
    return out


def _nan(v: Any, k: int) -> None:
    v.x = float("nan")


def _fast(v: Any, k: int) -> None:
    v.x = 40.0


def _spikes(v: Any, k: int) -> None:
    if k % 25 == 3:
        v.x = 40.0


def _warns(*words: str) -> Callable[[Path, subprocess.CompletedProcess[str]], str | None]:
    """The run warns on stderr (one `warning:` line holding every word)."""

    def check(_: Path, done: subprocess.CompletedProcess[str]) -> str | None:
        lines = [ln for ln in done.stderr.splitlines() if ln.startswith("warning: ")]
        if any(all(w in ln for w in words) for ln in lines):
            return None
        return f"no warning line with {words} (stderr: {done.stderr.strip()[-300:]!r})"

    return check


def _case(category: str, name: str, build: Callable[[Path], list[str]], **kw: Any) -> Case:
    return Case(category, name, build, max_seconds=20.0, **kw)


def _cases() -> list[Case]:
    refused = [
        ("misspelt depth_topic", ("keyframes.depth_topic=/bar30/presure",), {},
         ("keyframes.depth_topic", "/bar30/presure", "/bar30/pressure [sensor_msgs/msg/FluidPressure]")),
        ("misspelt dvl_topic", ("keyframes.dvl_topic=/dvl/twst",), {},
         ("keyframes.dvl_topic", "/dvl/twst", "/dvl/twist")),
        ("misspelt imu_topic", ("keyframes.imu_topic=/imu/data",), {},
         ("keyframes.imu_topic", "/imu/data", "/mavros/imu/data")),
        ("misspelt navigation_topic", ("keyframes.navigation_topic=/odom",), {},
         ("/odom", "keyframes.navigation_topic")),
        ("misspelt horizontal_topic", ("keyframes.horizontal_topic=/oculus/m750d",), {},
         ("/oculus/m750d", "keyframes.horizontal_topic")),
        ("depth_topic naming an IMU", ("keyframes.depth_topic=/mavros/imu/data",), {},
         ("/mavros/imu/data", "no depth, fluid_pressure or pose field")),
        ("FluidPressure in kPa", (), {"edit": _pressure(1e-3)},
         ("/bar30/pressure", "not absolute pressure in Pa")),
        ("FluidPressure in bar", (), {"edit": _pressure(1e-5)},
         ("/bar30/pressure", "not absolute pressure in Pa")),
        ("every DVL sample NaN", (), {"edit": _dvl(_nan)},
         ("/dvl/twist", "none of the", "non-finite")),
        ("every DVL sample at 40 m/s", (), {"edit": _dvl(_fast)},
         ("/dvl/twist", "faster than 5 m/s", "keyframes.dvl_max_velocity_mps")),
        ("two pressure topics, none named", (), {"edit": _twice_pressure},
         ("/bar30/pressure", "/mavros/imu/static_pressure", "keyframes.depth_topic")),
        ("no IMU for the DVL", (), {"edit": _drop("/mavros/imu/data")},
         ("keyframes.navigation_topic",)),
    ]  # fmt: skip
    cases = [
        _case(
            "exit codes",
            name,
            lambda w, s=sets, k=kw: _bag(w, *s, **k),
            check=names(*words),
        )
        for name, sets, kw, words in refused
    ]
    warned = [
        ("sonar frames not in any tf tree", {"tf": False}, ("default mount", "m750d_link")),
        ("DVL and IMU frames not in any tf tree", {"tf": False}, ("dvl", "default mount")),
        ("DVL spikes at 40 m/s", {"edit": _dvl(_spikes)}, ("dropped", "faster than 5 m/s", "DVL samples")),
        ("no depth sensor", {"edit": _drop("/bar30/pressure")}, ("no depth topic", "z = 0")),
        ("a /tf edge that changes", {"edit": _changing_tf}, ("/tf", "base_link->dvl_head", "changes", "first value")),
        ("config mount over the recording's", {"sets": ("keyframes.horizontal_mount_xyz_m=[0.4, 0, 0]",)},
         ("horizontal_mount_xyz_m overrides", "m750d_link")),
        ("config IMU mount over the recording's", {"sets": ("keyframes.imu_mount_rpy_deg=[180, 0, -90]",)},
         ("imu_mount_rpy_deg overrides", "imu_link")),
    ]  # fmt: skip
    for name, kw, words in warned:
        sets = kw.pop("sets", ())

        def build(w: Path, s: tuple[str, ...] = sets, k: dict[str, Any] = kw) -> list[str]:
            return _bag(w, *s, **k)

        cases.append(_case("trust", name, build, expect_exit=(0,), check=_warns(*words)))
    mapped = [
        ("DVL at 1.0 m/s", {"speed": 1.0}),
        ("DVL at 2.0 m/s", {"speed": 2.0}),
        ("pose navigation + Bar30 depth_topic", {"navigation": "odometry", "sets": ("keyframes.depth_topic=/bar30/pressure",)}),
    ]  # fmt: skip
    for name, kw in mapped:
        sets = kw.pop("sets", ())

        def build2(w: Path, s: tuple[str, ...] = sets, k: dict[str, Any] = kw) -> list[str]:
            return _bag(w, *s, **k)

        cases.append(_case("trust", name, build2, expect_exit=(0,), check=_quiet))
    return cases


def _quiet(_: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    """Mapped right: no warning at all (nothing substituted or dropped)."""
    warnings = [ln for ln in done.stderr.splitlines() if ln.startswith("warning: ")]
    return None if not warnings else f"unexpected warning: {warnings[0][:200]!r}"


CASES: list[Case] = _cases()
