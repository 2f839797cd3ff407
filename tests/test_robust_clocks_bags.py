"""Clocks set back in ROS 1 bags and rosbag2 sqlite3 bags, and sonar pings whose clock
jumps forward (issue 52, root 5).

Both bag formats hand messages sorted by time, but store them in the order they arrived
(a ROS 1 bag's chunks and offsets, a sqlite bag's row ids): the readers find a clock set
back from that order, drop what was recorded behind, and say so naming the topic."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Writer as Bag1Writer
from rosbags.rosbag2 import Writer as Bag2Writer
from test_readers_mcap import T0, odom_msg
from test_robust_clocks import _nav, _pings, _write

from sonarmap.pipeline.formats.rosmsg import ros1_typestore, ros2_typestore
from sonarmap.pipeline.readers import open_recording, open_source
from sonarmap.schemas.topics import ODOMETRY_TYPE
from tests.fixtures.ingest import odometry

S = 1_000_000_000
NAV = "/odometry/dead_reckoning"
# 0..12 s, then the clock is set back 8 s: 4.1..10 s again, at another place.
FIRST = [T0 + int(k * 0.1 * S) for k in range(121)]
AGAIN = [T0 + int((4.1 + k * 0.1) * S) for k in range(60)]


def _bag1(path: Path, chunk: int) -> Path:
    """A ROS 1 bag with the navigation written in the order recorded (not sorted)."""
    store = ros1_typestore()
    with Bag1Writer(path) as bag:
        bag.chunk_threshold = chunk
        conn = bag.add_connection(NAV, ODOMETRY_TYPE, typestore=store)
        for t, x in [(t, 0.5 * (t - T0) / S) for t in FIRST] + [(t, 100.0) for t in AGAIN]:
            bag.write(conn, t, store.serialize_ros1(odometry(t, (x, 0.0, 0.0), ros1=True), ODOMETRY_TYPE))
    return path


def _bag2_sqlite(path: Path) -> Path:
    store = ros2_typestore()
    with Bag2Writer(path, version=8) as bag:
        conn = bag.add_connection(NAV, ODOMETRY_TYPE, typestore=store)
        for t, x in [(t, 0.5 * (t - T0) / S) for t in FIRST] + [(t, 100.0) for t in AGAIN]:
            msg = odom_msg(t, x, 0.0, 0.0, 0.0)
            bag.write(conn, t, store.serialize_cdr(msg, ODOMETRY_TYPE))
    return path


def _check(source: Any) -> None:
    lines = [w for w in source.warnings if "runs backwards" in w]
    assert len(lines) == 1, source.warnings
    assert f"{NAV}: the clock runs backwards: dropped 60 of 181 messages" in lines[0]
    assert "7.9 s back" in lines[0]
    # The index's count less the dropped: no "the bag's index says" warning on top.
    assert not [w for w in source.warnings if "index says" in w], source.warnings
    t = source.times(NAV)
    assert len(t) == 121 and np.all(np.diff(t) > 0)
    xs = [float(m.pose.pose.position.x) for _, _, m in source.messages([NAV])]
    assert len(xs) == 121 and max(xs) < 7.0  # none of the set-back run (x = 100) is read
    # Asked by time, a dropped message sharing no time with a kept one is not read.
    assert [m for _, _, m in source.messages([NAV], times=[AGAIN[1]])] == []


def test_ros1_bag_clock_set_back_is_dropped_one_chunk(tmp_path: Path) -> None:
    _check(open_source(_bag1(tmp_path / "d.bag", 1 << 20)))


def test_ros1_bag_clock_set_back_is_dropped_many_chunks(tmp_path: Path) -> None:
    _check(open_source(_bag1(tmp_path / "d.bag", 2000)))


def test_sqlite_bag_clock_set_back_is_dropped(tmp_path: Path) -> None:
    _check(open_source(_bag2_sqlite(tmp_path / "dive")))


def test_sonar_pings_jumping_forward_are_warned(tmp_path: Path) -> None:
    # 1 Hz pings for 10 s, then nothing until an hour later.
    events = _pings(10) + [(t + 3600 * S, tp, ty, m) for t, tp, ty, m in _pings(10)]
    nav = _nav([k * 0.1 for k in range(100)] + [3600 + k * 0.1 for k in range(100)], 0.0)
    rec = open_recording(_write(tmp_path / "d.mcap", events + nav))
    assert len(rec.ping_times_ns("horizontal")) == 20
    lines = [w for w in rec.source.warnings if "jumps forward" in w]
    assert len(lines) == 1, rec.source.warnings
    assert "/sonar/horizontal: the clock jumps forward" in lines[0]
    assert "1 time(s)" in lines[0] and "3591 s" in lines[0]
    assert "nothing is mapped across a jump" in lines[0]


def test_steady_sonar_pings_give_no_jump_warning(tmp_path: Path) -> None:
    nav = _nav([k * 0.1 for k in range(200)], 0.0)
    rec = open_recording(_write(tmp_path / "d.mcap", _pings(20) + nav))
    rec.ping_times_ns("horizontal")
    assert not [w for w in rec.source.warnings if "jumps forward" in w]
