"""`sonarmap view`: serve a recording's finished run to Foxglove over WebSocket."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from sonarmap.pipeline.commands._common import CONFIG_OPT, SET_OPT, STORE_OPT, cli_graph

__all__ = ["register", "view"]


def view(
    ctx: typer.Context,
    dataset: Path = typer.Argument(..., help="Recording whose finished run to serve."),
    config: Path | None = CONFIG_OPT,
    set_: list[str] | None = SET_OPT,
    store: Path = STORE_OPT,
    port: int = typer.Option(8765, "--port", help="0: any free port."),
) -> None:
    """Serve DATASET's finished run to Foxglove (WebSocket) until Ctrl-C.

    The run of this config, found as `status` finds it, on ws://127.0.0.1:PORT;
    computes nothing, and checks every file against its manifest first.
    """
    from sonarmap.pipeline.api import RunRequest, plan_status
    from sonarmap.pipeline.engine.errors import SourceError
    from sonarmap.pipeline.engine.text import display_path
    from sonarmap.pipeline.live.session import check_port, live_session

    check_port(port, "--port")
    request = RunRequest(dataset, config_path=config, overrides=set_ or (), store_dir=store)
    run_ctx, planned, _model, unplanned = plan_status(request, cli_graph(ctx))
    hits = [p for p in planned if p.hit]
    if not hits:
        raise SourceError(
            f"{display_path(str(dataset))}: no finished stage for this config in store "
            f"{display_path(str(store))}; run `sonarmap run` on it first"
        )
    from sonarmap.pipeline.engine.store.integrity import verify_artifact_dir

    for p in hits:  # a shared store's files are checked before anyone sees them
        ref = run_ctx.store.get(p.stage.name, p.key)
        if ref is not None:
            verify_artifact_dir(ref.path, ref.manifest)
    with live_session(True, port=port, option="--port") as session:
        assert session.feed is not None
        for p in hits:
            session.feed.add(p.stage.name, run_ctx.store.artifact_dir(p.stage.name, p.key))
        missing = [p.stage.name for p in planned if not p.hit] + list(unplanned)
        note = f"; not run yet: {', '.join(missing)}" if missing else ""
        print(f"view: {len(hits)} finished stages{note}", file=sys.stderr, flush=True)


def register(app: typer.Typer) -> None:
    app.command("view")(view)
