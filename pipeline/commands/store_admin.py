"""`sonarmap ls` and `sonarmap gc`: list and collect artifacts."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from sonarmap.pipeline.commands._common import JSON_OPT, STORE_OPT, emit_json

__all__ = ["gc", "ls", "register"]


def ls(store: Path = STORE_OPT, json_: bool = JSON_OPT) -> None:
    """List the artifacts in the store."""
    from sonarmap.pipeline.commands._errors import one_line
    from sonarmap.pipeline.engine.store.artifact_store import ArtifactRef, ArtifactStore
    from sonarmap.pipeline.engine.text import display_path

    opened = ArtifactStore(store)  # a file there is refused, naming it
    if not store.is_dir():  # a mistyped --store would otherwise look like an empty one
        where = display_path(store)
        typer.echo(f"warning: {where}: no store there yet (no run has written to it)", err=True)
    items = list(opened.scan())
    rows: list[dict[str, Any]] = [
        {
            "stage": r.stage,
            "key": r.key,
            "created_at": r.manifest.get("created_at"),
            "bytes": sum(int(f["size"]) for f in r.manifest["files"].values()),
            "path": str(r.path),
        }
        for r in items
        if isinstance(r, ArtifactRef)
    ]
    broken = [str(p) for p in items if not isinstance(p, ArtifactRef)]
    # One line per directory that is not an artifact; the listing goes on regardless.
    for line in broken:
        typer.echo(f"warning: {one_line(line)} (`sonarmap gc` removes it)", err=True)
    if json_:
        emit_json({"store": str(store), "artifacts": rows, "broken": broken})
        return
    from rich.console import Console
    from rich.markup import escape as markup_escape
    from rich.table import Table

    from sonarmap.pipeline.engine.text import display_path

    # The store's name as text, never as rich markup (a folder named "[red]x") or raw bytes.
    table = Table(title=markup_escape(display_path(store)))
    for col in ("stage", "key", "created", "MB"):
        table.add_column(col)
    for r in rows:
        table.add_row(r["stage"], r["key"][:16], str(r["created_at"]), f"{r['bytes'] / 1e6:.2f}")
    Console().print(table)


def gc(
    store: Path = STORE_OPT,
    dry_run: bool = typer.Option(False, "--dry-run", help="Only say what would go."),
    broken: bool = typer.Option(
        False, "--broken", help="Also re-hash every artifact and remove those that fail."
    ),
    json_: bool = JSON_OPT,
) -> None:
    """Remove unreferenced artifacts, stray directories and killed runs' leftovers.

    Artifacts of runs in progress, and the finished stages of interrupted runs, are kept."""
    from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
    from sonarmap.pipeline.engine.store.disk import disk_error

    try:
        report = ArtifactStore(store).gc(dry_run=dry_run, broken=broken)
    except OSError as err:  # a read-only or vanished store: one line, exit 2
        raise disk_error(err, store) from err
    if json_:
        emit_json(report)
        return
    verb = "would remove" if dry_run else "removed"
    for line in report["broken"]:
        typer.echo(f"{verb} {line}", err=True)
    typer.echo(
        f"{verb} {len(report['removed'])} artifacts ({report['bytes_freed'] / 1e6:.1f} MB, "
        f"{len(report['broken'])} broken), {report.get('units_removed', 0)} work units, "
        f"{report['tmp_removed']} leftovers of killed runs; "
        f"kept {report['kept']}"
        + (f", {report['live_runs']} runs in progress" if report["live_runs"] else "")
    )


def register(app: typer.Typer) -> None:
    app.command("ls")(ls)
    app.command("gc")(gc)
