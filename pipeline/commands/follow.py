"""`sonarmap follow`: map an MCAP recording while it is being written."""

from __future__ import annotations

import signal
import sys
from pathlib import Path

import typer

from sonarmap.pipeline.commands._common import (
    CONFIG_OPT,
    JSON_OPT,
    NO_FIGURES_OPT,
    SET_OPT,
    STORE_OPT,
    WORKERS_OPT,
    cli_graph,
)

__all__ = ["follow", "register"]

INTERRUPTED = 130
"""Exit status after Ctrl-C (128 + SIGINT, as a shell reports it)."""


def follow(
    ctx: typer.Context,
    dataset: Path = typer.Argument(
        ...,
        help="MCAP file, or rosbag2 directory of MCAP files, being written (it may hold "
        "nothing yet, but must exist).",
    ),
    config: Path | None = CONFIG_OPT,
    set_: list[str] | None = SET_OPT,
    store: Path = STORE_OPT,
    workers: int | None = WORKERS_OPT,
    no_figures: bool = NO_FIGURES_OPT,
    json_: bool = JSON_OPT,
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress on stderr."),
    port: int = typer.Option(8765, "--port", help="Port of the live view (0: any free)."),
    every_s: float = typer.Option(
        2.0, "--every-s", min=0.0, help="Least time between two map updates, in seconds."
    ),
    poll_s: float = typer.Option(
        0.25, "--poll-s", min=0.01, max=60.0, help="Time between two looks at the file, in seconds."
    ),
    idle_timeout_s: float | None = typer.Option(
        None,
        "--idle-timeout-s",
        min=0.0,
        help="End as if closed after this long without growth, in seconds (default: wait for the "
        "footer, or Ctrl-C).",
    ),
) -> None:
    """Map DATASET (MCAP file or rosbag2 directory) while it is written, live in Foxglove.

    Every --every-s, when new records arrived, maps what is complete so far (up to
    voxelize, no figures, in a background thread) and publishes it on ws://127.0.0.1:PORT
    as `run --live` does. Meanwhile each new keyframe is mapped at once, dead-reckoned
    from the last update, and published on /map/preview (an MCAP file; not a bag).
    When the recording is closed (its MCAP footer written; a bag: its metadata.yaml
    naming every file, each closed) or idle for --idle-timeout-s, runs it as `run`
    does (same artifacts, same summary) and exits 0; Ctrl-C exits 130, keeping every
    stage already committed.
    """
    import tempfile

    from sonarmap.pipeline.api import RunRequest, run_dataset
    from sonarmap.pipeline.commands._errors import writes_under
    from sonarmap.pipeline.commands.run import print_run
    from sonarmap.pipeline.engine.config.load import load_config
    from sonarmap.pipeline.engine.hashing import ChangedWhileRead
    from sonarmap.pipeline.engine.run.progress import StageProgress
    from sonarmap.pipeline.live.follow import Follower, FollowOptions
    from sonarmap.pipeline.live.growing import check_followable
    from sonarmap.pipeline.live.session import check_port, live_session

    check_port(port, "--port")
    check_followable(dataset)
    graph = cli_graph(ctx)
    # The whole config is checked before the first look at the recording.
    load_config(graph.config_stages, config, set_ or (), graph.extra_sections)
    request = RunRequest(
        dataset,
        config_path=config,
        overrides=set_ or (),
        store_dir=store,
        workers=workers,
        figures=not no_figures,
    )

    def say(line: str) -> None:
        if not quiet:
            print(line, file=sys.stderr, flush=True)

    options = FollowOptions(every_s=every_s, poll_s=poll_s, idle_timeout_s=idle_timeout_s)
    try:
        with (
            writes_under(store),
            live_session(True, port=port, linger=False, option="--port") as view,
            tempfile.TemporaryDirectory(prefix="sonarmap-follow-") as scratch,
        ):
            assert view.feed is not None
            follower = Follower(
                request,
                graph,
                Path(scratch),
                on_stage=view.feed.on_stage,
                drain=view.feed.server.drain,
                publish=view.feed.server.submit,
                say=say,
                options=options,
            )
            while True:
                follower.follow()
                ended = "closed" if follower.closed else "idle"
                say(f"follow: {dataset} {ended} after {len(follower.updates)} updates: final run")
                try:
                    with StageProgress(enabled=not quiet) as progress:
                        result, summary = run_dataset(
                            request,
                            graph,
                            on_start=progress.on_start,
                            on_stage=view.chain(progress.on_stage),
                            scores=json_,
                        )
                except ChangedWhileRead:
                    if follower.closed:
                        raise
                    # --idle-timeout-s ended a recorder's pause, not its recording
                    say(
                        f"follow: {dataset} grew again during the final run, after"
                        f" {idle_timeout_s:g} s without growth: following on (a recorder"
                        " that pauses longer wants a longer --idle-timeout-s)"
                    )
                    continue
                break
            follower.clear_preview()
            view.feed.server.drain()
            print_run(result, summary, json_=json_, quiet=quiet)
    except KeyboardInterrupt:
        _say_interrupted()
        raise typer.Exit(INTERRUPTED) from None
    except SystemExit as stop:
        if stop.code in (128 + signal.SIGTERM, 128 + signal.SIGHUP):  # unwound as Ctrl-C is
            _say_interrupted()
        raise


def _say_interrupted() -> None:
    print(
        "follow: interrupted; every stage committed so far stays in the store",
        file=sys.stderr,
        flush=True,
    )


def register(app: typer.Typer) -> None:
    app.command("follow")(follow)
