"""`follow`'s preview, piece by piece: the keyframe rule continued from the last keyframe
keeps what it keeps on the whole recording, a chained pose is the navigation's motion
applied to the anchor, and the window of a snapshot holds every message logged since
its start (and the channels they need). The preview of a real mission against a batch
run is in test_follow.py (it shares that file's simulated mission)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap.writer import Writer

from sonarmap.pipeline.live.growing import McapSnapshot
from sonarmap.pipeline.live.window import RecordWindow
from sonarmap.stages.kernels.geometry import pose_from_se3
from sonarmap.stages.kernels.poses import pose_matrix
from sonarmap.stages.kernels.preview import chained_poses
from sonarmap.stages.keyframes.stage import continue_selection, select_keyframes


def _walk(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A vehicle's candidate times [ns] and poses: a random walk with turns and stops."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.integers(50_000_000, 400_000_000, n)).astype(np.int64)
    step = rng.normal(0.0, 0.4, (n, 3)) * (rng.random((n, 1)) < 0.8)
    poses = np.zeros((n, 6))
    poses[:, :3] = np.cumsum(step, axis=0)
    poses[:, 5] = np.cumsum(rng.normal(0.0, 0.15, n))
    poses[:, 3:5] = rng.normal(0.0, 0.02, (n, 2))
    return t, poses


def test_selection_continued_piece_by_piece_equals_the_batch_selection() -> None:
    args = (2.0, np.deg2rad(30.0), 1_000_000_000)
    for seed in range(5):
        t, poses = _walk(600, seed)
        batch, reasons = select_keyframes(t, poses, *args)
        assert 20 < len(batch) < 500  # the walk makes the rule keep some, not all
        rng = np.random.default_rng(seed)
        cuts = np.sort(rng.choice(np.arange(1, 600), 30, replace=False))
        kept, why = [int(batch[0])], [reasons[0]]
        for lo, hi in zip([0, *cuts], [*cuts, 600], strict=True):  # data arrives in pieces
            last = kept[-1]
            after = np.arange(max(lo, last + 1), hi)
            new, r = continue_selection(t[last], poses[last], t[after], poses[after], *args)
            kept.extend(int(i) for i in after[new])
            why.extend(r)
        assert kept == batch.tolist()
        assert why == reasons


def test_a_chained_pose_is_the_navigation_motion_applied_to_the_anchor() -> None:
    _, nav = _walk(8, 7)
    slam = nav[3] + np.array([0.5, -1.0, 0.1, 0.0, 0.0, 0.3])  # SLAM moved the anchor
    T = chained_poses(pose_matrix(slam)[0], nav[3], nav)
    np.testing.assert_allclose(pose_from_se3(T[3]), slam, atol=1e-12)
    motion = np.linalg.inv(pose_matrix(nav[3])[0]) @ pose_matrix(nav[6])[0]
    np.testing.assert_allclose(np.linalg.inv(T[3]) @ T[6], motion, atol=1e-12)


def _recording() -> bytes:
    """Two topics whose channels are registered late (inside chunks), small chunks."""
    buf = io.BytesIO()
    w = Writer(buf, chunk_size=200)
    w.start(profile="ros2", library="test")
    schema = w.register_schema("std_msgs/msg/String", "ros2msg", b"string data")
    a = w.register_channel("/a", "cdr", schema)
    for i in range(80):
        if i == 40:
            b = w.register_channel("/b", "cdr", schema)
        channel = b if i >= 40 and i % 2 else a
        w.add_message(channel, 1_000_000_000 + i * 10_000_000, bytes([i]) * (30 + i), 0, i)
    w.finish()
    return buf.getvalue()


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    with path.open("rb") as f:
        return [(c.topic, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages()]


def test_the_window_holds_every_message_since_its_start(tmp_path: Path) -> None:
    data = _recording()
    source = tmp_path / "rec.mcap"
    snap = McapSnapshot(source, tmp_path / "snap.mcap")
    window = RecordWindow(snap.path)
    everything = None
    for cut in (3000, 6000, len(data)):  # the recording grows
        source.write_bytes(data[:cut])
        snap.update()
        window.update(snap.size)
        everything = _messages(snap.path)
        for since in (0, 1_300_000_000, 1_555_000_000, 9_000_000_000):
            window.write(since, tmp_path / "w.mcap")
            got = _messages(tmp_path / "w.mcap")
            wanted = [m for m in everything if m[1] >= since]
            # whole records are cut: a little before `since` may come too, never less
            assert [m for m in got if m[1] >= since] == wanted
            assert len(got) - len(wanted) < 10
    assert everything is not None and {m[0] for m in everything} == {"/a", "/b"}


def test_a_preview_that_cannot_read_its_window_says_so_once_and_follow_goes_on(
    tmp_path: Path,
) -> None:
    import time

    from sonarmap.pipeline.api import RunRequest
    from sonarmap.pipeline.engine.errors import SourceError
    from sonarmap.pipeline.graph import default_graph
    from sonarmap.pipeline.live.follow import Follower

    source = tmp_path / "dive.mcap"
    source.write_bytes(b"")
    said: list[str] = []
    follower = Follower(
        RunRequest(source), default_graph(), tmp_path, say=said.append, publish=lambda *a: None
    )
    assert follower.preview is not None
    window = str(follower.preview.window_path)

    def poll() -> list:
        raise SourceError(f"{window}: no navigation topic")

    follower.preview.poll = poll  # type: ignore[method-assign]
    assert not follower._preview_step(time.time)
    assert not follower._preview_step(time.time)
    assert said == ["follow: no preview (window: no navigation topic); the full updates go on"]
