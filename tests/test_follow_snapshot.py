"""The snapshot of an MCAP file being written (`sonarmap.pipeline.live.growing`): cut at
any byte, it is a closed MCAP holding exactly the messages of the complete records before
the cut, for the `mcap` library and for sonarmap's own reader; grown piece by piece it
ends as the one-shot snapshot of the whole file; and `follow` refuses what it cannot read
in one line, exit 2."""

from __future__ import annotations

import io
import os
import struct
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from mcap.records import Chunk, DataEnd, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import Writer
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.live.bag_snapshot import SETTLE_S, BagSnapshot
from sonarmap.pipeline.live.growing import MAGIC, McapSnapshot, mcap_closed
from sonarmap.pipeline.readers import open_source

TOPICS = ("/a", "/b")


def _recording(numbers: range = range(60)) -> bytes:
    """A small ROS 2 MCAP: two topics, messages of varied sizes, small chunks (several
    messages in some, one in others), attachments and metadata after the messages."""
    buf = io.BytesIO()
    w = Writer(buf, chunk_size=300)
    w.start(profile="ros2", library="test")
    schema = w.register_schema("std_msgs/msg/String", "ros2msg", b"string data")
    ids = [w.register_channel(t, "cdr", schema) for t in TOPICS]
    for i in numbers:
        size = 20 + (i * 37) % 400
        w.add_message(ids[i % 2], 1_000_000_000 + i * 10_000_000, bytes([i]) * size, 0, i)
    w.add_attachment(0, 0, "scene.yaml", "application/yaml", b"x: 1\n")
    w.add_metadata("m", {"k": "v"})
    w.finish()
    return buf.getvalue()


def _complete_messages(data: bytes) -> list[tuple[int, list[tuple[int, int, bytes]]]]:
    """Per top-level record of the data section: its end offset and its messages
    (channel id, log time, data), by mcap's own stream reader."""
    spans, pos = [], len(MAGIC)
    while pos + 9 <= len(data):
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        spans.append(pos + 9 + length)
        pos += 9 + length
    out = []
    records = StreamReader(io.BytesIO(data), skip_magic=False, emit_chunks=True).records
    for end, rec in zip(spans, records, strict=False):
        if isinstance(rec, DataEnd):
            break
        inner = breakup_chunk(rec) if isinstance(rec, Chunk) else [rec]
        msgs = [(m.channel_id, m.log_time, bytes(m.data)) for m in inner if isinstance(m, Message)]
        out.append((end, msgs))
    return out


def _snapshot(tmp_path: Path, data: bytes) -> tuple[McapSnapshot, Path]:
    src = tmp_path / "growing.mcap"
    src.write_bytes(data)
    snap = McapSnapshot(src, tmp_path / "snap.mcap")
    snap.update()
    return snap, snap.path


def test_a_cut_file_reads_back_exactly_the_complete_messages(tmp_path: Path) -> None:
    data = _recording()
    records = _complete_messages(data)
    assert len(records) > 10 and sum(len(m) for _, m in records) == 60
    ends = [e for e, _ in records]
    cuts = sorted({8, 9, 20, *ends[:3], ends[5] - 1, ends[5] + 4, len(data) // 2, len(data) - 30})
    cuts += [len(data), *range(40, len(data), len(data) // 7)]
    for cut in cuts:
        want = [m for end, msgs in records if end <= cut for m in msgs]
        snap, path = _snapshot(tmp_path, data[:cut])
        assert mcap_closed(path)
        got = [
            (c.id, m.log_time, bytes(m.data))
            for _, c, m in make_reader(path.open("rb")).iter_messages()
        ]
        assert got == want, cut
        assert snap.last_log_time_ns == (max(t for _, t, _ in want) if want else None)
        source = open_source(path)
        counts = {t.topic: t.count for t in source.topics()}
        per_topic = {t: sum(1 for c, *_ in want if c == 1 + TOPICS.index(t)) for t in TOPICS}
        assert counts == {t: n for t, n in per_topic.items() if n}, cut
        for topic in counts:
            cid = 1 + TOPICS.index(topic)
            assert source.times(topic).tolist() == [t for c, t, _ in want if c == cid]


def test_grown_piece_by_piece_it_is_the_whole_files_snapshot(tmp_path: Path) -> None:
    data = _recording()
    src = tmp_path / "rec.mcap"
    src.write_bytes(b"")
    snap = McapSnapshot(src, tmp_path / "grown.mcap")
    seen = []
    with src.open("ab") as f:
        for i in range(0, len(data), 97):
            f.write(data[i : i + 97])
            f.flush()
            growth = snap.update()
            seen.append(growth.closed)
    assert seen[-1] and not any(seen[:-1])  # closed once the footer and magic are there
    (tmp_path / "whole").mkdir()
    _, path = _snapshot(tmp_path / "whole", data)
    assert snap.path.read_bytes() == path.read_bytes()
    assert snap.size < len(data)  # the summary is not copied: the snapshot has none


def test_a_bag_directory_is_followed_file_by_file_until_its_metadata(tmp_path: Path) -> None:
    bag, scratch = tmp_path / "dive", tmp_path / "scratch"
    bag.mkdir()
    parts = [_recording(range(0, 30)), _recording(range(30, 60))]
    now = [0.0]
    snap = BagSnapshot(bag, scratch, clock=lambda: now[0])

    def by_topic(path: Path) -> dict[str, list[int]]:
        source = open_source(path)
        return {t.topic: source.times(t.topic).tolist() for t in source.topics()}

    def seen() -> list[int]:
        return sorted(t for ts in by_topic(snap.path).values() for t in ts)

    def times(data: bytes, cut: int | None = None) -> list[int]:
        records = _complete_messages(data)
        return sorted(t for end, msgs in records if end <= (cut or end) for _, t, _ in msgs)

    (bag / "dive_0.mcap").write_bytes(parts[0][: len(parts[0]) // 2])
    assert not snap.update().closed
    assert seen() == times(parts[0], len(parts[0]) // 2)
    (bag / "dive_0.mcap").write_bytes(parts[0])  # split: the next file opens
    (bag / "dive_1.mcap").write_bytes(parts[1][:500])
    assert not snap.update().closed
    assert seen() == times(parts[0]) + times(parts[1], 500)
    (bag / "dive_1.mcap").write_bytes(parts[1])
    assert not snap.update().closed  # every file closed, but no metadata.yaml yet
    meta = {
        "rosbag2_bagfile_information": {
            "storage_identifier": "mcap",
            "relative_file_paths": ["dive_0.mcap", "dive_1.mcap"],
        }
    }
    (bag / "metadata.yaml").write_text(yaml.safe_dump(meta))
    assert not snap.update().closed  # it must look finished for SETTLE_S, with nothing new
    now[0] += SETTLE_S
    growth = snap.update()
    assert growth.closed and growth.last_log_time_ns == 1_000_000_000 + 59 * 10_000_000
    assert seen() == times(parts[0]) + times(parts[1])
    assert by_topic(snap.path) == by_topic(bag)


def test_not_an_mcap_file_is_refused(tmp_path: Path) -> None:
    src = tmp_path / "x.mcap"
    src.write_bytes(b"not an mcap file at all")
    with pytest.raises(SourceError, match=r"x\.mcap: not an MCAP file"):
        McapSnapshot(src, tmp_path / "s.mcap").update()
    src.write_bytes(MAGIC[:5])  # a recorder that has written less than the magic: wait
    assert McapSnapshot(src, tmp_path / "s.mcap").update().new_bytes == 0


def test_a_source_that_shrinks_while_followed_is_refused(tmp_path: Path) -> None:
    data = _recording()
    src = tmp_path / "growing.mcap"
    src.write_bytes(data[: len(data) // 2])
    snap = McapSnapshot(src, tmp_path / "s.mcap")
    assert snap.update().new_bytes > 0
    src.write_bytes(data[: len(data) // 4])
    with pytest.raises(SourceError, match=r"growing\.mcap: shrank from \d+ to \d+ bytes"):
        snap.update()


@pytest.mark.parametrize("what", ["junk", "missing", "sqlite bag", "ros1 bags", "fifo"])
def test_follow_refuses_what_it_cannot_read_in_one_line(tmp_path: Path, what: str) -> None:
    path = tmp_path / "dive.mcap"
    if what == "junk":
        path.write_bytes(b"junk" * 10)
    elif what == "sqlite bag":
        path.mkdir()
        (path / "dive_0.db3").write_bytes(b"SQLite format 3\x00")
    elif what == "ros1 bags":  # a folder that no recorder writing MCAP storage makes
        path.mkdir()
        (path / "dive.bag").write_bytes(b"#ROSBAG V2.0\n")
    elif what == "fifo":
        os.mkfifo(path)
    args = ["follow", str(path), "--store", str(tmp_path / "s"), "--port", "0", "-q"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "dive.mcap" in lines[0]


def test_a_bag_whose_metadata_is_written_at_each_split_is_followed_to_its_end(
    tmp_path: Path,
) -> None:
    """Campaign 13 #1: a recorder writing metadata.yaml at each split (naming only the
    closed first file) ended follow there, exit 0, with a quarter of the map."""
    bag, scratch = tmp_path / "dive", tmp_path / "scratch"
    bag.mkdir()
    parts = [_recording(range(0, 30)), _recording(range(30, 60))]
    now = [0.0]
    snap = BagSnapshot(bag, scratch, clock=lambda: now[0])

    def meta(names: list[str]) -> None:
        doc = {"rosbag2_bagfile_information": {"storage_identifier": "mcap",
                                               "relative_file_paths": names}}  # fmt: skip
        (bag / "metadata.yaml").write_text(yaml.safe_dump(doc))

    (bag / "dive_0.mcap").write_bytes(parts[0])
    meta(["dive_0.mcap"])  # the first split: its file closed, the next not opened yet
    assert not snap.update().closed
    now[0] += SETTLE_S / 2
    (bag / "dive_1.mcap").write_bytes(parts[1][:500])  # opened: still written
    assert not snap.update().closed
    now[0] += 10 * SETTLE_S
    assert not snap.update().closed  # an unlisted file being written is the next split
    (bag / "dive_1.mcap").write_bytes(parts[1])
    assert not snap.update().closed  # closed, but the metadata names it not yet
    meta(["dive_0.mcap", "dive_1.mcap"])
    assert not snap.update().closed
    now[0] += SETTLE_S
    assert snap.update().closed


def test_a_bag_waiting_for_a_footer_says_why(tmp_path: Path) -> None:
    """Campaign 13 #7: metadata.yaml written, a listed file without its footer: follow
    waited in silence."""
    bag = tmp_path / "dive"
    bag.mkdir()
    data = _recording(range(0, 30))
    (bag / "dive_0.mcap").write_bytes(data[: len(data) // 2])
    doc = {"rosbag2_bagfile_information": {"storage_identifier": "mcap",
                                           "relative_file_paths": ["dive_0.mcap"]}}  # fmt: skip
    (bag / "metadata.yaml").write_text(yaml.safe_dump(doc))
    snap = BagSnapshot(bag, tmp_path / "scratch")
    assert not snap.update().closed
    assert "lists every file, but dive_0.mcap has no MCAP footer yet" in snap.waiting


def test_a_recording_copied_over_the_followed_one_is_refused(tmp_path: Path) -> None:
    """Campaign 13 #2, #3: `cp other.mcap followed.mcap` keeps the inode; the new bytes were
    appended to the old recording's (a splice, silently) or read as a damaged record."""
    first, second = _recording(range(0, 40)), _recording(range(100, 140))
    assert first[:30] == second[:30] and first != second  # one writer, one header
    src = tmp_path / "dive.mcap"
    src.write_bytes(first[: len(first) // 2])
    snap = McapSnapshot(src, tmp_path / "snap.mcap")
    snap.update()
    with src.open("r+b") as f:  # copied over in place: same inode, longer than before
        f.write(second[: len(first) // 2 + 100])
    with pytest.raises(SourceError, match=r"written again while followed \(its bytes before"):
        snap.update()


def test_a_full_temporary_disk_is_named_not_the_store(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Campaign 13 #5: the snapshot's full disk was reported as `STORE: No space left`."""
    import errno

    from sonarmap.pipeline.engine.errors import OutputError

    src = tmp_path / "dive.mcap"
    src.write_bytes(_recording(range(0, 30)))
    snap = McapSnapshot(src, tmp_path / "tmp" / "snap.mcap")

    def full(*_: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(McapSnapshot, "_copy", full)
    with pytest.raises(OutputError, match=r"tmp: No space left on device \(follow's copy"):
        snap.update()


def test_a_file_no_writer_closed_is_read_with_a_warning(tmp_path: Path) -> None:
    """Campaign 13 #7: a file ending on a whole record but without its footer (a recorder
    that died, or one paused past --idle-timeout-s) was mapped with no word."""
    data = _recording(range(0, 30))
    records = _complete_messages(data)
    end = records[len(records) // 2][0]  # a record boundary inside the data section
    open_file = tmp_path / "open.mcap"
    open_file.write_bytes(data[:end])
    source = open_source(open_file)
    assert any("not closed (no MCAP footer)" in w for w in source.warnings), source.warnings
    closed = tmp_path / "closed.mcap"
    closed.write_bytes(data)
    assert not any("not closed" in w for w in open_source(closed).warnings)
    snap = McapSnapshot(open_file, tmp_path / "snap.mcap")  # follow's copy: closed by it
    snap.update()
    assert not any("not closed" in w for w in open_source(snap.path).warnings)
