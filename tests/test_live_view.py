"""Live view: a real Foxglove WebSocket client subscribes while a small simulated run
computes and receives every topic, the map as soon as voxelize finishes; then
`sonarmap run --live` and `sonarmap view` serve the finished run to a late client."""

from __future__ import annotations

import asyncio
import signal
import threading
import time
from pathlib import Path

import pytest
from foxglove_ws_client import Received, collect
from typer.testing import CliRunner

from sonarmap.pipeline.api import RunRequest, run_dataset
from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.errors import OutputError
from sonarmap.pipeline.graph import pipeline_stages
from sonarmap.pipeline.live.feed import LiveFeed
from sonarmap.pipeline.live.server import LiveServer
from sonarmap.stages.evaluate.foxglove_scene import TOPIC_SCHEMAS
from tests.fixtures.live_process import live_address, start_module, stderr_until

pytest.importorskip("websockets")


def _has_error_map(got: Received) -> bool:
    maps = got.messages.get("/map/semantic", [])
    return any("error" in [f.name for f in m.fields] for _, _, m in maps)


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from sonarmap.pipeline.training.datasets import Simulation, ensure_simulations, scene_path

    out = tmp_path_factory.mktemp("live") / "tiny.mcap"
    ensure_simulations([Simulation(scene_path("tiny"), 2, out, duration_s=30.0)], 1)
    return out


@pytest.fixture(scope="module")
def live_run(recording: Path) -> tuple[Path, Received, dict[str, float]]:
    """The run, computed with the client connected from the start."""
    store = recording.parent / "store"
    server = LiveServer(port=0)
    feed = LiveFeed(server, pipeline_stages())
    finished: dict[str, float] = {}
    errors: list[BaseException] = []

    def on_stage(result: object) -> None:
        finished[result.stage] = time.monotonic()  # type: ignore[attr-defined]
        feed.on_stage(result)

    def run() -> None:
        try:
            run_dataset(RunRequest(recording, store_dir=store), on_stage=on_stage)
        except BaseException as err:  # reported by the test, not lost in the thread
            errors.append(err)

    thread = threading.Thread(target=run)
    try:
        got = asyncio.run(
            collect(
                server.url,
                lambda g: _has_error_map(g) or (errors and not thread.is_alive()),
                timeout_s=120.0,
                on_subscribed=thread.start,
            )
        )
        thread.join(60)
    finally:
        server.stop()
    assert not errors, errors
    return store, got, finished


def test_each_topic_arrives_during_the_run_map_on_voxelize(
    live_run: tuple[Path, Received, dict[str, float]],
) -> None:
    _, got, finished = live_run
    # every topic but `follow`'s preview
    assert set(got.messages) == set(TOPIC_SCHEMAS) - {"/map/preview", "/trajectory/preview"}
    for ch in got.channels.values():
        assert ch["schemaName"] == f"foxglove.{TOPIC_SCHEMAS[ch['topic']]}"
        assert ch["encoding"] == "protobuf"
    first = {t: min(a for a, _, _ in m) for t, m in got.messages.items()}
    # published as each stage completes, after the stages it reads (classify and slam
    # read neither each other nor fuse, and run side by side with two workers)
    assert first["/sonar/horizontal/fan"] < first["/live/fused"] < first["/map/semantic"]
    assert first["/sonar/horizontal/fan"] < first["/objects"] < first["/map/semantic"]
    assert first["/sonar/horizontal/fan"] < first["/trajectory/slam"] < first["/map/semantic"]
    lag = first["/map/semantic"] - finished["voxelize"]
    assert 0.0 <= lag < 2.0, f"first map {lag:.2f} s after voxelize finished"
    first_map = got.messages["/map/semantic"][0][2]
    assert "error" not in [f.name for f in first_map.fields]  # voxelize's; evaluate adds it
    assert first_map.frame_id == "map" and len(first_map.data) > 0


def _serve(args: list[str], timeout_s: float = 60.0) -> tuple[Received, str, str, int]:
    """Start `sonarmap ARGS`, connect to the address it prints, collect, then Ctrl-C."""
    proc = start_module("sonarmap.pipeline", *args)
    try:
        url, head = live_address(proc)
        wanted = {"/sonar/horizontal/fan", "/trajectory/slam", "/objects", "/ground_truth/mesh"}
        got = asyncio.run(
            collect(
                url,
                lambda g: _has_error_map(g) and wanted <= set(g.messages),
                timeout_s=timeout_s,
            )
        )
        # Ctrl-C only once it serves on: the client can have everything while the run is
        # still finishing, and a Ctrl-C there stops the run (exit 130), as it should.
        head += stderr_until(proc, "live: serving")
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    return got, out, head + err, proc.returncode


def test_run_live_and_view_serve_the_finished_run_to_a_late_client(
    recording: Path, live_run: tuple[Path, Received, dict[str, float]]
) -> None:
    store = live_run[0]
    for args in (
        ["run", str(recording), "--store", str(store), "--live", "--live-port", "0", "-q"],
        ["view", str(recording), "--store", str(store), "--port", "0"],
    ):
        got, out, err, code = _serve(args)
        assert code == 0, err
        assert "Traceback" not in err and "error:" not in err
        assert _has_error_map(got)  # the finished run's map, with its errors
        assert {"/sonar/horizontal/fan", "/trajectory/slam", "/objects"} <= set(got.messages)
        assert got.server_info["name"] == "sonarmap"
        if args[0] == "run":
            assert "semantic/standard" in out  # the summary, before serving on


def test_view_without_a_finished_run_is_one_line_exit_2(tmp_path: Path) -> None:
    rec = tmp_path / "nothing.mcap"
    rec.write_bytes(b"")
    result = CliRunner().invoke(app, ["view", str(rec), "--store", str(tmp_path / "s")])
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "nothing.mcap" in lines[0]


def test_busy_port_is_refused_naming_it() -> None:
    first = LiveServer(port=0)
    try:
        with pytest.raises(OutputError, match=f":{first.port}"):
            LiveServer(port=first.port)
    finally:
        first.stop()


@pytest.mark.parametrize(
    "args",
    [["view", "r.mcap", "--port", "70000"], ["run", "r.mcap", "--live", "--live-port", "-1"]],
)
def test_port_out_of_range_is_one_line_exit_2(tmp_path: Path, args: list[str]) -> None:
    (tmp_path / "r.mcap").write_bytes(b"")
    args = [str(tmp_path / a) if a == "r.mcap" else a for a in args]
    result = CliRunner().invoke(app, [*args, "--store", str(tmp_path / "s")])
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --") and "port" in lines[0]
