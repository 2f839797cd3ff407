"""`sonarmap status`: which stages are cached, which would run, and why."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

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

if TYPE_CHECKING:
    from sonarmap.pipeline.engine.run.planned import PlannedStage
    from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore

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
        {"stage": p.stage.name, "key": p.key, "status": status, "reason": reason}
        for p in planned
        for status, reason in [_hit_or_damage(context.store, p)]
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
        styles=[_STYLES.get(r["status"], "yellow") for r in rows],
    )
    if not context.store.root.is_dir():  # a mistyped --store reads as a fresh one
        Console(stderr=True).print(f"no store at {store} yet: `run` creates it", markup=False)


_STYLES = {"hit": "green", "damaged": "red"}


def _hit_or_damage(store: ArtifactStore, planned: PlannedStage) -> tuple[str, str]:
    """(status, reason) of a planned stage; a hit whose files are not all there, at their
    sizes, is "damaged": the run that reads it stops there (a changed byte needs
    `show --verify`)."""
    from sonarmap.pipeline.engine.store.integrity import recovery_hint, size_damage

    if not planned.hit:
        return "miss", planned.reason
    ref = store.get(planned.stage.name, planned.key)
    damage = None if ref is None else size_damage(ref)
    if damage is None:
        return "hit", planned.reason
    return "damaged", f"{damage}: a run that reads it stops; {recovery_hint(planned.stage.name)}"


def register(app: typer.Typer) -> None:
    app.command("status")(status)
