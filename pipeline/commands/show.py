"""`sonarmap show`: an artifact's manifest and a preview of its files."""

from __future__ import annotations

from pathlib import Path

import typer

from sonarmap.pipeline.commands._common import JSON_OPT, STORE_OPT, emit_json
from sonarmap.pipeline.formats.strict_json import dumps_strict

__all__ = ["register", "show"]


def _preview(path: Path) -> str:
    if path.suffix == ".parquet":
        import pyarrow.parquet as pq

        table = pq.read_table(path)
        head = table.slice(0, 5).to_pylist()
        return (
            f"{table.num_rows} rows\n{table.schema.to_string(show_schema_metadata=False)}\n"
            + "\n".join(dumps_strict(r, indent=None, sort_keys=False) for r in head)
        )
    if path.suffix in (".json", ".md", ".tum", ".yaml"):
        text = path.read_text()
        return text if len(text) < 4000 else text[:4000] + "\n..."
    return f"{path.stat().st_size} bytes"


def show(
    target: str = typer.Argument(..., help="A stage name (its newest artifact) or a key prefix."),
    store: Path = STORE_OPT,
    verify: bool = typer.Option(False, "--verify", help="Re-hash every file against the manifest."),
    json_: bool = JSON_OPT,
) -> None:
    """Print an artifact's manifest and a preview of each file."""
    from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore

    st = ArtifactStore(store)
    ref = st.find(target)
    if verify:
        st.verify(ref)
        from sonarmap.pipeline.engine.store.integrity import check_required_files
        from sonarmap.pipeline.graph import required_files

        # Every listed file matched; one the stage always writes may still be unlisted.
        where = f"artifact {ref.stage}/{ref.key[:12]}"
        check_required_files(ref.stage, ref.manifest["files"], required_files(), where)
    if json_:
        emit_json({"path": str(ref.path), "verified": verify, "manifest": ref.manifest})
        return
    from rich.console import Console

    console = Console()
    console.rule(f"{ref.stage} {ref.key}")
    console.print(f"path: {ref.path}")
    if verify:
        console.print("[green]verified[/]: every file matches its sha256")
    console.print_json(dumps_strict(ref.manifest))
    for name in ref.manifest.get("files", {}):
        console.rule(name)
        try:
            preview = _preview(ref.file(name))
        except (OSError, ValueError) as err:  # pyarrow's ArrowInvalid is a ValueError
            preview = f"unreadable ({type(err).__name__}); check with `show --verify`"
        console.print(preview, markup=False, highlight=False)


def register(app: typer.Typer) -> None:
    app.command("show")(show)
