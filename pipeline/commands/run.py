"""`sonarmap run`: run (or reuse) every stage for one dataset."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from sonarmap.pipeline.commands._common import (
    CONFIG_OPT,
    JSON_OPT,
    NO_FIGURES_OPT,
    SET_OPT,
    STORE_OPT,
    WORKERS_OPT,
    cli_graph,
    emit_json,
)

__all__ = ["print_run", "register", "run"]


def run(
    ctx: typer.Context,
    dataset: Path = typer.Argument(..., help="Recording: ROS 2 MCAP, bag directory, ROS 1 bag."),
    config: Path | None = CONFIG_OPT,
    set_: list[str] | None = SET_OPT,
    until: str | None = typer.Option(None, "--until", help="Stop after this stage."),
    force: list[str] | None = typer.Option(None, "--force", help="Recompute this stage."),
    store: Path = STORE_OPT,
    workers: int | None = WORKERS_OPT,
    no_figures: bool = NO_FIGURES_OPT,
    json_: bool = JSON_OPT,
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress on stderr."),
    live: bool = typer.Option(
        False, "--live", help="Serve each finished stage to Foxglove (WebSocket, 127.0.0.1)."
    ),
    live_port: int = typer.Option(8765, "--live-port", help="Port of --live (0: any free)."),
) -> None:
    """Run the mapping pipeline on DATASET, reusing every cached stage."""
    from sonarmap.pipeline.api import RunRequest, run_dataset
    from sonarmap.pipeline.commands._errors import writes_under
    from sonarmap.pipeline.engine.run.progress import StageProgress
    from sonarmap.pipeline.live.session import live_session

    with writes_under(store), live_session(live, port=live_port) as view:
        with StageProgress(enabled=not quiet) as progress:
            request = RunRequest(
                dataset,
                config_path=config,
                overrides=set_ or (),
                store_dir=store,
                until=until,
                force=force or (),
                workers=workers,
                figures=not no_figures,
            )
            result, summary = run_dataset(
                request,
                cli_graph(ctx),
                on_start=progress.on_start,
                on_stage=view.chain(progress.on_stage),
                scores=json_,
            )
        print_run(result, summary, json_=json_, quiet=quiet)


def print_run(result: Any, summary: dict[str, Any], *, json_: bool, quiet: bool) -> None:
    """What `run` prints after its stages: the JSON document, or the summary, the sensors
    and the front end (`follow` prints the same after its final run)."""
    sensors = _sensors(result)
    from sonarmap.pipeline.report_cli import front_end_of

    front_end = front_end_of(result)
    trajectory = _trajectory(result)
    if json_:
        doc = {
            **summary,
            **sensors,
            **front_end,
            **({"trajectory_source": trajectory} if trajectory else {}),
        }
        emit_json({**result.to_json(), "summary": doc})
        return
    from sonarmap.pipeline.report_cli import (
        front_end_lines,
        print_summary,
        progress_shares_stdout,
    )

    print_summary(result, summary, stages_listed=not quiet and progress_shares_stdout())
    _print_sensors(sensors)
    if trajectory:
        typer.echo(f"trajectory: {trajectory}")
    for line in front_end_lines(front_end):
        typer.echo(line)


def _trajectory(result: Any) -> str:
    """Where the map's poses came from when SLAM was asked for and fell back ("" else):
    the slam artifact's `fallback` (its summary.json)."""
    import json

    ref = result.artifacts.get("slam")
    path = None if ref is None else Path(ref.path) / "summary.json"
    if path is None or not path.is_file():
        return ""
    return str(json.loads(path.read_text()).get("fallback") or "")


def _sensors(result: Any) -> dict[str, Any]:
    """Where each role's topic, frame and values came from, and the reader's warnings
    (substitutions and drops, with counts), from the keyframes artifact's sensors.json."""
    import json

    ref = result.artifacts.get("keyframes")
    path = None if ref is None else Path(ref.path) / "sensors.json"
    if path is None or not path.is_file():
        return {}
    doc = json.loads(path.read_text())
    return {
        "provenance": doc.get("provenance", {}),
        "reader_warnings": (doc.get("source") or {}).get("warnings", []),
    }


def _print_sensors(sensors: dict[str, Any]) -> None:
    """One line per role: topic [type], frame and the source of its values."""
    for role, info in sorted((sensors.get("provenance") or {}).items()):
        parts = [f"{info.get('topic') or '-'}"]
        if info.get("frame"):
            parts.append(f"frame {info['frame']}")
        sources = {k: v for k, v in info.items() if k.startswith("mount_") or k == "source"}
        sources.update({k: v for k, v in info.items() if k == "surface_pressure"})
        parts += [f"{k} from {v}" for k, v in sorted(sources.items())]
        typer.echo(f"{role}: " + ", ".join(parts))
    # The reader's warnings are not repeated here: the run prints each as a `warning:`
    # line, from the keyframes stage when it computes, from its artifact when cached.


def register(app: typer.Typer) -> None:
    app.command("run")(run)
