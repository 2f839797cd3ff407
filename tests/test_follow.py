"""`sonarmap follow`: one process writes a small simulated mission slowly (the `mcap`
Writer, small chunks, flushed, paced by the recording's own times; one MCAP file, or a
rosbag2 directory of split files), another follows it;
a Foxglove client sees a map before the writer is done, and the artifacts `follow` leaves
are those of a batch `run` of the finished file (same keys, same bytes). Ctrl-C: 130."""

from __future__ import annotations

import asyncio
import re
import signal
import time
from contextlib import suppress
from pathlib import Path

import pytest
from foxglove_ws_client import Received, collect

from sonarmap.pipeline.api import RunRequest, run_dataset
from tests.fixtures.live_process import live_address, start_module

websockets = pytest.importorskip("websockets")


@pytest.fixture(scope="module")
def mission(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from sonarmap.pipeline.training.datasets import Simulation, ensure_simulations, scene_path

    out = tmp_path_factory.mktemp("follow") / "tiny.mcap"
    ensure_simulations([Simulation(scene_path("tiny"), 2, out, duration_s=30.0)], 1)
    return out


def _artifacts(store: Path, result_keys: dict[str, str]) -> dict[str, dict[str, bytes]]:
    """Each stage's files but its manifest (which records when and how long)."""
    return {
        stage: {
            p.name: p.read_bytes()
            for p in sorted((store / stage / key).iterdir())
            if p.name != "manifest.json"
        }
        for stage, key in result_keys.items()
    }


@pytest.mark.realtime
@pytest.mark.parametrize("kind", ["mcap", "bag"])
def test_follow_maps_while_written_and_ends_as_run(
    mission: Path, tmp_path: Path, kind: str
) -> None:
    store = tmp_path / "store"
    if kind == "mcap":
        growing = tmp_path / "dive.mcap"
        growing.write_bytes(b"")  # the recorder has opened it
        split: tuple[str, ...] = ()
    else:  # split files every 10 s of the mission, metadata.yaml at the end
        growing = tmp_path / "dive"
        growing.mkdir()
        split = ("--split-s", "10")
    follow = start_module(
        *("sonarmap.pipeline", "follow", str(growing), "--store", str(store), "--port", "0"),
        *("-j", "1", "--every-s", "1", "--json"),
    )
    writer = None
    try:
        url, head = live_address(follow)
        # 30 s of mission written in 15 s: several updates fit in before its end.
        writer = start_module(
            *("sonarmap.pipeline.live.replay", str(mission), str(growing), "--speed", "2"),
            *("--log-writes", *split),
        )
        seen: list[Received] = []

        def until(g: Received) -> bool:
            seen[:] = [g]
            return follow.poll() is not None

        with suppress(websockets.ConnectionClosed):  # the server goes when follow ends
            asyncio.run(collect(url, until, timeout_s=240.0))
        got = seen[-1]
        out, err = follow.communicate(timeout=60)
        w_out, w_err = writer.communicate(timeout=60)
    finally:
        for proc in (follow, writer):
            if proc is not None and proc.poll() is None:
                proc.kill()
    err = head + err
    assert follow.returncode == 0, err
    assert writer.returncode == 0, w_err
    assert "Traceback" not in err and "error:" not in err
    done = float(re.search(r"done \d+ ([\d.]+)", w_out).group(1))  # type: ignore[union-attr]
    maps = got.messages.get("/map/standard", [])
    # `collect` stamps arrivals with time.monotonic(); the writer reports time.time()
    offset = time.time() - time.monotonic()
    early = [t_log for arrived, t_log, _ in maps if arrived + offset < done]
    assert early, f"no map before the writer finished: {err}"
    assert len(re.findall(r"follow: update \d+: .* keyframes, map voxels", err)) >= 1, err
    assert maps[-1][1] > early[0]  # the final map reaches further than the first one
    previews = [m for m in got.messages.get("/map/preview", []) if len(m[2].data)]
    if kind == "mcap":  # each keyframe mapped at once between the full updates
        assert previews, err
        assert re.search(r"follow: preview keyframe \d+: \d+ points", err), err
        assert got.messages.get("/trajectory/preview"), err
    else:  # a bag's split files: full updates only
        assert not previews and "preview keyframe" not in err

    import json

    doc = json.loads(out)
    keys = {s["stage"]: s["key"] for s in doc["stages"]}
    batch_store = tmp_path / "batch"
    result, _ = run_dataset(RunRequest(growing, store_dir=batch_store, workers=1))
    assert keys == {s.stage: s.key for s in result.stages}
    assert _artifacts(store, keys) == _artifacts(batch_store, keys)


@pytest.mark.parametrize(("sig", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_ctrl_c_stops_cleanly_with_130(
    mission: Path, tmp_path: Path, sig: signal.Signals, status: int
) -> None:
    """Ctrl-C exits 130, `kill` 143; both say so (campaign 13 #8: SIGTERM said nothing)."""
    cut = tmp_path / "cut.mcap"
    data = mission.read_bytes()
    cut.write_bytes(data[: len(data) // 3])  # a recording that stopped growing, not closed
    follow = start_module(
        *("sonarmap.pipeline", "follow", str(cut), "--store", str(tmp_path / "s")),
        *("--port", "0", "-j", "1"),
    )
    try:
        _, head = live_address(follow)
        assert follow.stderr is not None
        line = ""
        while not line.startswith("follow: update 1:"):  # the first update, mapped or not
            line = follow.stderr.readline()
            assert line, head
        follow.send_signal(sig)
        _, err = follow.communicate(timeout=60)
    finally:
        if follow.poll() is None:
            follow.kill()
    assert follow.returncode == status, err
    assert "follow: interrupted" in err and "Traceback" not in err


def test_the_loop_ends_on_the_footer_or_after_the_idle_timeout(
    mission: Path, tmp_path: Path
) -> None:
    from sonarmap.pipeline.graph import default_graph
    from sonarmap.pipeline.live.follow import Follower, FollowOptions

    said: list[str] = []
    never = FollowOptions(every_s=1e9, poll_s=0.05)  # watch only: no map update
    closed = Follower(
        RunRequest(mission), default_graph(), tmp_path, say=said.append, options=never
    )
    assert closed.follow() == [] and closed.closed  # a finished file: at once
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(mission.read_bytes()[:100_000])
    idle = FollowOptions(every_s=1e9, poll_s=0.05, idle_timeout_s=0.3)
    follower = Follower(
        RunRequest(cut), default_graph(), tmp_path / "s", say=said.append, options=idle
    )
    updates = follower.follow()
    assert not follower.closed
    # the first update comes with the first data; this cut holds no sonar message yet
    assert [u.number for u in updates] == [1] and "no sonar topic" in updates[0].problem
    assert said[0].startswith("follow: update 1: 0.0 MB read, no map yet (snapshot: no sonar")
    assert said[1:] == ["follow: no growth for 0.3 s: mapping what was written"]


def test_the_preview_maps_keyframes_as_a_batch_run(mission: Path, tmp_path: Path) -> None:
    """Anchored at a keyframe of a batch run (its calibration, its pose), the preview of
    the finished file maps the keyframes after it as the batch run does: the same
    keyframes, poses (the navigation, as no SLAM moved the anchor) and fused points."""
    from dataclasses import replace

    import numpy as np
    import pyarrow.parquet as pq

    from sonarmap.pipeline.engine.config.load import load_config
    from sonarmap.pipeline.graph import default_graph
    from sonarmap.pipeline.live.growing import McapSnapshot
    from sonarmap.pipeline.live.preview import Preview, anchor_of
    from sonarmap.stages.kernels.poses import pose_matrix

    graph = default_graph()
    request = RunRequest(mission, store_dir=tmp_path / "s", until="fuse", workers=1)
    result, _ = run_dataset(replace(request, figures=False), graph)
    anchor = anchor_of(result, {s.name: s for s in graph.stages})
    assert anchor is not None

    kfs = pq.read_table(Path(result.artifacts["keyframes"].path) / "keyframes.parquet")
    fused = pq.read_table(Path(result.artifacts["fuse"].path) / "fused.parquet")
    cols = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
    nav = np.stack([kfs.column(c).to_numpy() for c in cols], axis=1)
    k = 1  # anchored at the second keyframe: the others come from the preview
    assert kfs.num_rows >= k + 4
    t_k = int(kfs.column("t_ns")[k].as_py())
    anchor = replace(
        anchor, keyframe_id=k, t_ns=t_k, nav_pose=nav[k], T_world=pose_matrix(nav[k])[0]
    )
    config = load_config(graph.config_stages, None, (), graph.extra_sections)
    preview = Preview(McapSnapshot(mission, tmp_path / "p.mcap"), config, tmp_path / "w.mcap")
    assert preview.poll() == []  # no anchor yet: nothing mapped
    preview.set_anchor(anchor)
    new = preview.poll()
    # all but those held back at the very end (a partner ping may still come)
    assert kfs.num_rows - k - 2 <= len(new) <= kfs.num_rows - k - 1
    ids = [p.keyframe_id for p in new]
    assert ids == list(range(k + 1, k + 1 + len(new)))
    assert [p.t_ns for p in new] == kfs.column("t_ns").to_pylist()[k + 1 : k + 1 + len(new)]
    np.testing.assert_allclose([p.pose for p in new], nav[k + 1 : k + 1 + len(new)], atol=1e-9)
    kf_col = fused.column("keyframe_id").to_numpy()
    xyz = np.stack([fused.column(c).to_numpy() for c in ("x_m", "y_m", "z_m")], axis=1)
    assert sum(len(p.xyz) for p in new) > 0
    for p in new:
        np.testing.assert_array_equal(p.xyz, xyz[kf_col == p.keyframe_id])
    # the next full update reaches keyframe k + 2: the preview keeps those after it
    t_next = int(kfs.column("t_ns")[k + 2].as_py())
    pose_next = pose_matrix(nav[k + 2])[0]
    preview.set_anchor(
        replace(anchor, keyframe_id=k + 2, t_ns=t_next, nav_pose=nav[k + 2], T_world=pose_next)
    )
    assert [p.keyframe_id for p in preview.keyframes] == ids[2:]
    np.testing.assert_allclose(
        [p.pose for p in preview.keyframes], nav[k + 3 : k + 1 + len(new)], atol=1e-9
    )
    assert preview.poll() == []  # nothing newer: none mapped twice


def test_a_recorder_that_grows_again_after_the_idle_timeout_is_followed_on(
    mission: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Campaign 13 #4: a recorder paused longer than --idle-timeout-s, then wrote on; the
    final run stopped with "changed while sonarmap read it ... use `sonarmap follow`"."""
    from typer.testing import CliRunner

    import sonarmap.pipeline.api as api
    from sonarmap.pipeline.cli import app
    from sonarmap.pipeline.engine.errors import SourceError
    from sonarmap.pipeline.engine.hashing import changed_while_read

    cut = tmp_path / "cut.mcap"
    cut.write_bytes(mission.read_bytes()[:100_000])
    final_runs: list[int] = []

    def final_run(request: RunRequest, *_: object, **__: object) -> None:
        if request.until is not None:
            raise SourceError("an update: no map")  # follow's updates stop at the map
        final_runs.append(1)
        if len(final_runs) == 1:
            raise changed_while_read(str(cut))  # the recorder wrote on during it
        raise SourceError("second final run reached")

    monkeypatch.setattr(api, "run_dataset", final_run)
    res = CliRunner().invoke(app, ["follow", str(cut), "--store", str(tmp_path / "s"),
                                   "--port", "0", "--every-s", "1000", "--poll-s", "0.05",
                                   "--idle-timeout-s", "0.3"])  # fmt: skip
    assert res.exit_code == 2 and "second final run reached" in res.stderr, res.output
    assert "grew again during the final run, after 0.3 s without growth: following on" in (
        res.stderr
    )
    assert (
        len(final_runs) == 2
        and len(re.findall(r" idle after \d+ updates: final run", res.stderr)) == 2
    )
