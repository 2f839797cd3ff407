"""`sonarmap status`: which stages are cached, which would run, and why."""

from __future__ import annotations

from pathlib import Path

import typer

from sonarmap.pipeline.commands._common import (
    CONFIG_OPT,
    JSON_OPT,
    NO_FIGURES_OPT,
    SET_OPT,
    STORE_OPT,
    cli_graph,
    emit_json,
)

__all__ = ["register", "status"]


def status(
    ctx: typer.Context,
    dataset: Path = typer.Argument(..., help="Recording to plan for."),
    config: Path | None = CONFIG_OPT,
    set_: list[str] | None = SET_OPT,
    until: str | None = typer.Option(None, "--until", help="Plan up to this stage."),
    store: Path = STORE_OPT,
    no_figures: bool = NO_FIGURES_OPT,
    json_: bool = JSON_OPT,
) -> None:
    """Show, without computing anything, which stages hit the cache and why others miss."""
    from sonarmap.pipeline.api import RunRequest, plan_status

    request = RunRequest(
        dataset,
        config_path=config,
        overrides=set_ or (),
        store_dir=store,
        until=until,
        figures=not no_figures,
    )
    context, planned, model, unplanned = plan_status(request, cli_graph(ctx))
    rows = []
    if model is not None:
        status = "hit" if model.hit else "miss"
        rows.append({"stage": "train", "key": model.key, "status": status, "reason": model.reason})
    rows += [
        {
            "stage": p.stage.name,
            "key": p.key,
            "status": "hit" if p.hit else "miss",
            "reason": p.reason,
        }
        for p in planned
    ]
    rows += [
        {
            "stage": name,
            "key": "",
            "status": "miss",
            "reason": "planned once the model is trained",
        }
        for name in unplanned
    ]
    order = {s.name: i for i, s in enumerate(context.stages)}  # graph order, train first
    rows.sort(key=lambda r: order.get(r["stage"], -1))
    if json_:
        emit_json({"dataset": str(dataset), "store": str(store), "stages": rows})
        return
    from rich.console import Console

    from sonarmap.pipeline.tables import print_table

    print_table(
        Console(),
        f"{dataset} ({context.dataset.fingerprint[:12]})",
        ("stage", "status", "key", "reason"),
        [(r["stage"], r["status"], r["key"][:12], r["reason"]) for r in rows],
        styles=["green" if r["status"] == "hit" else "yellow" for r in rows],
    )


def register(app: typer.Typer) -> None:
    app.command("status")(status)
