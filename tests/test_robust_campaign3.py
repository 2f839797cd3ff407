"""Adversarial campaign 3 (clocks, readers, follow): times past what the artifacts hold,
damaged ROS 1 bags, bag metadata that lies, files `follow` would wait on forever, and a
recording with a years-long gap in its clock."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import yaml
from test_readers_mcap import T0, odom_msg
from test_robust_clocks import NAV, S, _pings, _write
from test_robust_lists_and_recordings import _bag

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.live.bag_snapshot import SETTLE_S, BagSnapshot
from sonarmap.pipeline.live.growing import McapSnapshot
from sonarmap.pipeline.readers import open_recording, open_source
from sonarmap.pipeline.readers.clock import LAST_STAMP_NS, Backwards
from sonarmap.pipeline.readers.ros1_source import Ros1Source
from sonarmap.schemas.topics import ODOMETRY_TYPE
from sonarmap.stages.slam.config import SlamConfig
from sonarmap.stages.slam.frontend import run_slam


def test_log_times_past_2038_are_refused_naming_the_topic(tmp_path: Path) -> None:
    """ROS 2 header stamps hold int32 seconds: the keyframes artifact could not carry such
    a time (it failed deep in the stage with a struct error)."""
    late = LAST_STAMP_NS + S
    nav = [
        (late + k * S, NAV, ODOMETRY_TYPE, odom_msg(0, 0.5 * k, 0.0, 0.0, 0.0)) for k in range(5)
    ]
    path = _write(tmp_path / "d.mcap", _pings(5) + nav)
    with pytest.raises(
        SourceError, match=rf"d\.mcap: {NAV}: log time t_ns={late + 4 * S} is after 2038"
    ):
        open_recording(path)


def test_a_time_past_2_63_is_named_as_the_recorder_wrote_it() -> None:
    line = Backwards(np.array([False, True]), -1, 5).warning("x: /nav")
    assert "t_ns=18446744073709551615, past 2^63" in line


def test_follow_refuses_a_short_file_that_cannot_become_an_mcap(tmp_path: Path) -> None:
    src = tmp_path / "x.mcap"
    src.write_bytes(b"X")
    with pytest.raises(SourceError, match="not an MCAP file"):
        McapSnapshot(src, tmp_path / "s.mcap").update()


def _closed_bag(tmp_path: Path, listed: list[str], extra: str | None = None) -> Path:
    bag = tmp_path / "dive"
    bag.mkdir()
    _write(bag / "dive_0.mcap", _pings(3))
    if extra:
        _write(bag / extra, _pings(2))
    meta = {
        "rosbag2_bagfile_information": {"storage_identifier": "mcap", "relative_file_paths": listed}
    }
    (bag / "metadata.yaml").write_text(yaml.safe_dump(meta))
    return bag


def test_follow_of_a_closed_bag_missing_a_listed_file_is_refused(tmp_path: Path) -> None:
    bag = _closed_bag(tmp_path, ["dive_0.mcap", "dive_1.mcap"])
    with pytest.raises(SourceError, match=r"lists dive_1\.mcap, which is not in"):
        BagSnapshot(bag, tmp_path / "scratch").update()


def test_follow_of_a_closed_bag_does_not_wait_for_an_unlisted_file(tmp_path: Path) -> None:
    bag = _closed_bag(tmp_path, ["dive_0.mcap"], extra="stray.mcap")
    now = [0.0]
    snap = BagSnapshot(bag, tmp_path / "scratch", clock=lambda: now[0])
    assert not snap.update().closed  # finished-looking: it must stay so for SETTLE_S
    now[0] = SETTLE_S
    assert snap.update().closed


@pytest.mark.parametrize(
    ("listed", "message"),
    [(["dive_0.mcap", "./dive_0.mcap"], "twice"), ([], "lists no file")],
)
def test_bag_metadata_listing_a_file_twice_or_none_is_refused(
    tmp_path: Path, listed: list[str], message: str
) -> None:
    bag = _bag(tmp_path, "dive_0.mcap")
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())
    meta["rosbag2_bagfile_information"]["relative_file_paths"] = listed
    (bag / "metadata.yaml").write_text(yaml.safe_dump(meta))
    with pytest.raises(SourceError, match=message):
        open_source(bag)


def _ros1(reader: Any) -> Ros1Source:
    source = object.__new__(Ros1Source)
    source.path, source._reader = Path("dive.bag"), reader
    source._conns = {NAV: [SimpleNamespace(topic=NAV, msgtype=ODOMETRY_TYPE)]}
    return source


def test_a_ros1_index_pointing_at_no_message_is_one_line() -> None:
    from rosbags.rosbag1 import ReaderError

    def messages(**_: Any) -> Any:
        raise ReaderError("Header could not be read from file.")
        yield

    with pytest.raises(
        SourceError, match=rf"dive\.bag: the bag's index points at no message of {NAV}"
    ):
        list(_ros1(SimpleNamespace(messages=messages)).messages([NAV]))


def test_a_ros1_message_its_definition_does_not_describe_names_topic_and_type() -> None:
    conn = SimpleNamespace(topic=NAV, msgtype=ODOMETRY_TYPE)

    def deserialize(raw: bytes, msgtype: str) -> Any:
        raise ValueError("ROS1 message size mismatch")

    def messages(**_: Any) -> Any:
        yield conn, 7, b"\x00"

    source = _ros1(SimpleNamespace(messages=messages, deserialize=deserialize))
    with pytest.raises(SourceError, match=rf"{NAV}: the {ODOMETRY_TYPE} message at t_ns=7"):
        list(source.messages([NAV]))


def test_slam_across_a_years_long_clock_gap_keeps_the_navigation() -> None:
    """All streams jump 3 years forward together: the step across the gap is the longest
    step the odometry's noise model is meant for, and the heading bias's walk is at most a
    half turn (GTSAM found the system indeterminate before)."""
    dr = np.column_stack([np.arange(10.0), np.zeros(10), np.zeros(10)])
    t_s = np.arange(10.0) * 2.0
    t_s[5:] += 3 * 365.25 * 86400
    result = run_slam(SlamConfig(), dr, [np.zeros((0, 2))] * 10, t_s)
    np.testing.assert_allclose(result.poses[:, :2], dr[:, :2], atol=1e-6)


def test_one_sample_stamped_an_hour_late_is_dropped_alone(tmp_path: Path) -> None:
    """The stray time is taken out, not every later sample behind it (40 of 61 were)."""
    times = [k * 0.5 for k in range(61)]
    nav = [
        (
            T0 + int(s * S) + (3600 * S if k == 20 else 0),
            NAV,
            ODOMETRY_TYPE,
            odom_msg(0, 0.5 * s, 0.0, 0.0, 0.0),
        )
        for k, s in enumerate(times)
    ]
    rec = open_recording(_write(tmp_path / "d.mcap", _pings(30) + nav))
    assert len(rec.navigation()) == 60
    [line] = [w for w in rec.source.warnings if "runs backwards" in w]
    assert (
        f"{NAV}: the clock runs backwards: dropped 1 of 61 messages recorded with a time ahead"
        in line
    )


@pytest.mark.parametrize("late_s", [0.0, 3.0])
def test_a_sonar_logged_seconds_from_its_stamps_is_warned(tmp_path: Path, late_s: float) -> None:
    """Pings are posed by log time; one sonar's log times 3 s from its header stamps while
    the navigation's are not is named (the map was 1.4 m off without a word). The
    navigation's offset is a recorded fact of the reading, the sonar's that of a ping."""
    from sonarmap.stages.keyframes.recording_facts import stamp_offset_warning

    late = int(late_s * S)
    pings = [
        (t + (late if "horizontal" in topic else 0), topic, ty, m) for t, topic, ty, m in _pings(20)
    ]
    nav = [
        (T0 + k * S // 2, NAV, ODOMETRY_TYPE, odom_msg(T0 + k * S // 2, 0.25 * k, 0.0, 0.0, 0.0))
        for k in range(50)
    ]
    rec = open_recording(_write(tmp_path / "d.mcap", pings + nav))
    rec.navigation()
    nav_offset = rec.describe()["navigation_stamp_offset_s"]
    assert nav_offset == 0.0
    t = int(rec.ping_times_ns("horizontal")[3])
    next(iter(rec.pings("horizontal", [3], labels=False)))
    assert rec.stamp_offset_s("horizontal", t) == pytest.approx(late_s)
    line = stamp_offset_warning(
        "d.mcap", "horizontal", rec.stamp_offset_s("horizontal", t), nav_offset
    )
    if late_s:
        assert line is not None and "d.mcap: horizontal sonar: its log times are +3 s" in line
        assert "the navigation's +0 s" in line
    else:
        assert line is None
    # Stamps in another time base (time since boot) are not compared.
    assert stamp_offset_warning("d.mcap", "horizontal", 1.7e9, 0.0) is None


def test_pings_inside_a_jump_of_the_navigation_clock_are_counted(tmp_path: Path) -> None:
    """The navigation's clock jumps an hour, the sonar's does not: the pings in between are
    posed by interpolation across the hour, and the warning says how many."""
    nav_s = [k * 0.5 for k in range(20)] + [3600 + k * 0.5 for k in range(20)]
    nav = [
        (T0 + int(s * S), NAV, ODOMETRY_TYPE, odom_msg(0, 0.1 * s, 0.0, 0.0, 0.0)) for s in nav_s
    ]
    rec = open_recording(_write(tmp_path / "d.mcap", _pings(30) + nav))
    rec.navigation()
    [line] = [w for w in rec.source.warnings if "jumps forward" in w]
    assert f"{NAV}: the clock jumps forward 1 time(s)" in line
    assert "20 of 30 horizontal pings fall inside one" in line


def test_no_pair_says_how_far_apart_the_sonars_ping() -> None:
    from sonarmap.stages.kernels.pairing import PosedPairs, pair_pings
    from sonarmap.stages.keyframes.recording_facts import no_keyframe

    h = np.arange(10) * S
    v = h + S // 4  # the vertical sonar 0.25 s late
    pairs = pair_pings(h, v, S // 10)
    posed = PosedPairs(pairs, h, v, np.zeros((0, 6)), np.zeros(0, np.int64))
    assert "0 sonar pairs" in str(no_keyframe(posed))
    assert "the pings are a median 0.25 s apart, over keyframes.pair_tolerance_s" in str(
        no_keyframe(posed)
    )


def test_one_sonar_has_no_mount_or_warning_for_the_other(shared_data: Path) -> None:
    """`convert` of an ARIS file (one sonar) warned of a default mount for a vertical
    sonar the recording does not have."""
    from sonarmap.pipeline.readers import ReaderOptions, SourceRecording
    from sonarmap.pipeline.readers.roles import detect_roles

    path = shared_data / "aris" / "sample.aris"
    source = open_source(path)
    roles = detect_roles(path, source.topics(), ReaderOptions.from_config(None), require_pair=False)
    rec = SourceRecording(source, ReaderOptions.from_config(None), roles)
    assert sorted(rec.mountings()) == ["horizontal"]
    assert not any("vertical:" in w for w in source.warnings), source.warnings
    assert any("horizontal:" in w for w in source.warnings), source.warnings


def test_a_closed_mcap_damaged_in_the_middle_is_refused_not_read_as_cut(tmp_path: Path) -> None:
    """A third of a closed file zeroed: its footer and summary are intact, so what cannot
    be read before them is damage; it was read up to the damage and mapped with a warning
    that the file was cut (8 s of 30 s)."""
    path = _write(tmp_path / "d.mcap", _pings(40), chunk=600)
    data = bytearray(path.read_bytes())
    third = len(data) // 3
    data[third : 2 * third] = bytes(third)
    path.write_bytes(bytes(data))
    with pytest.raises(
        SourceError, match=r"d\.mcap: corrupt MCAP: unreadable at byte offset \d+, before"
    ):
        open_source(path)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(bytes(data[: third + 100]))  # no footer: a power cut, read up to it
    assert any("truncated or corrupt MCAP" in w for w in open_source(cut).warnings)


def test_a_followed_file_replaced_by_another_is_refused(tmp_path: Path) -> None:
    """`mv other.mcap dive.mcap` while followed: reading the new file on from the old one's
    offset splices two recordings (it failed on a 'record' of absurd length instead)."""
    src = tmp_path / "dive.mcap"
    _write(src, _pings(5))
    snap = McapSnapshot(src, tmp_path / "s.mcap")
    assert snap.update().new_bytes > 0
    other = _write(tmp_path / "other.mcap", _pings(8))
    other.replace(src)
    with pytest.raises(SourceError, match=r"dive\.mcap: replaced by another file while followed"):
        snap.update()


def test_an_unchunked_mcap_keeps_its_attachments(tmp_path: Path) -> None:
    """Its messages are read sequentially (no chunk indexes); its scene mesh was dropped
    with them, so the evaluation had no ground truth without saying why."""
    from mcap.writer import CompressionType, Writer

    from sonarmap.pipeline.formats.rosmsg import ros2_typestore

    path = tmp_path / "flat.mcap"
    with path.open("wb") as f:
        w = Writer(f, use_chunking=False, compression=CompressionType.NONE)
        w.start("ros2", "test")
        schema = w.register_schema("nav_msgs/msg/Odometry", "ros2msg", b"")
        channel = w.register_channel(NAV, "cdr", schema)
        msg = odom_msg(T0, 0.0, 0.0, 0.0, 0.0)
        data = bytes(ros2_typestore().serialize_cdr(msg, ODOMETRY_TYPE))
        w.add_message(channel, T0, data, T0)
        w.add_attachment(T0, T0, "scene.ply", "application/octet-stream", b"ply\n")
        w.finish()
    assert open_source(path).attachments() == {"scene.ply": b"ply\n"}


def test_a_chunk_index_past_the_end_of_the_file_reads_the_file_sequentially(tmp_path: Path) -> None:
    """Sorted last, its chunk's messages seemed recorded after every other's: a false
    'clock runs backwards' warning, while `topics` called the file corrupt."""
    from sonarmap.pipeline.readers.mcap_index import index_locations
    from sonarmap.pipeline.readers.mcap_integrity import IndexCorrupt

    path = _write(tmp_path / "d.mcap", _pings(6), chunk=600)
    from mcap.reader import make_reader

    with path.open("rb") as f:
        chunks = list(make_reader(f).get_summary().chunk_indexes)
    bad = chunks[0].__class__(**{**vars(chunks[0]), "chunk_start_offset": path.stat().st_size})
    with pytest.raises(IndexCorrupt, match="points past the end of the file"):
        index_locations(path, [bad, *chunks[1:]])


def test_a_ros1_index_listing_a_message_twice_is_refused() -> None:
    """A chunk info pointing at the wrong chunk: one chunk read twice, another lost; it
    was mapped with a warning about duplicate timestamps."""
    conn = SimpleNamespace(id=1, topic="/sonar/vertical", msgtype="x")
    entries = [(10, 100, 0), (11, 100, 40), (11, 100, 40), (12, 200, 0)]
    source = _ros1(SimpleNamespace(readers=[SimpleNamespace(indexes={1: entries})]))
    with pytest.raises(
        SourceError, match=r"lists a /sonar/vertical message twice \(chunk at byte offset 100\)"
    ):
        source._refuse_repeated_entries(conn, source._entry_table(conn))
    source._reader.readers[0].indexes[1] = entries[:2] + entries[3:]
    source._refuse_repeated_entries(conn, source._entry_table(conn))  # no repeat
