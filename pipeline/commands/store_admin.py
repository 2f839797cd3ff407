"""`sonarmap ls` and `sonarmap gc`: list and collect artifacts."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from pipeline.commands._common import JSON_OPT, STORE_OPT, emit_json

__all__ = ["register"]


def register(app: typer.Typer) -> None:
    @app.command("ls")
    def ls(store: Path = STORE_OPT, json_: bool = JSON_OPT) -> None:
        """List the artifacts in the store."""
        from pipeline.engine.store import ArtifactStore

        rows: list[dict[str, Any]] = [
            {
                "stage": r.stage,
                "key": r.key,
                "created_at": r.manifest.get("created_at"),
                "bytes": sum(int(f["size"]) for f in r.manifest.get("files", {}).values()),
                "path": str(r.path),
            }
            for r in ArtifactStore(store).iter_artifacts()
        ]
        if json_:
            emit_json({"store": str(store), "artifacts": rows})
            return
        from rich.console import Console
        from rich.table import Table

        table = Table(title=str(store))
        for col in ("stage", "key", "created", "MB"):
            table.add_column(col)
        for r in rows:
            table.add_row(
                r["stage"], r["key"][:16], str(r["created_at"]), f"{r['bytes'] / 1e6:.2f}"
            )
        Console().print(table)

    @app.command("gc")
    def gc(
        store: Path = STORE_OPT,
        dry_run: bool = typer.Option(False, "--dry-run", help="Only say what would go."),
        json_: bool = JSON_OPT,
    ) -> None:
        """Remove artifacts no recorded run references, and stale temporaries."""
        from pipeline.engine.store import ArtifactStore

        report = ArtifactStore(store).gc(dry_run=dry_run)
        if json_:
            emit_json(report)
            return
        verb = "would remove" if dry_run else "removed"
        typer.echo(
            f"{verb} {len(report['removed'])} artifacts ({report['bytes_freed'] / 1e6:.1f} MB), "
            f"{report['tmp_removed']} stale temporaries; kept {report['kept']}"
        )
