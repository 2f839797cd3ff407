"""`sonarmap push|pull REMOTE [KEY...]`: share artifacts through any fsspec URL."""

from __future__ import annotations

from pathlib import Path

import typer

from pipeline.commands._common import JSON_OPT, STORE_OPT, emit_json
from pipeline.training.model_cache import DEFAULT_MODEL_CACHE

__all__ = ["register"]

_UPSTREAM = typer.Option(True, "--upstream/--no-upstream", help="Include upstream artifacts.")


def register(app: typer.Typer) -> None:
    @app.command("push")
    def push(
        remote: str = typer.Argument(..., help="Directory or fsspec URL (s3://, gs://, ...)."),
        targets: list[str] | None = typer.Argument(None, help="Stage names or key prefixes."),
        store: Path = STORE_OPT,
        upstream: bool = _UPSTREAM,
        model_cache: Path = typer.Option(
            DEFAULT_MODEL_CACHE,
            "--model-cache",
            help="Model cache (`<training.directory>/store`) holding a model's training data.",
        ),
        json_: bool = JSON_OPT,
    ) -> None:
        """Copy artifacts (and by default everything upstream of them) to REMOTE."""
        from pipeline.engine.share import push as do_push
        from pipeline.engine.store import ArtifactStore

        pushed = do_push(
            ArtifactStore(store),
            remote,
            targets or (),
            with_upstream=upstream,
            fallbacks=[ArtifactStore(model_cache)],
        )
        if json_:
            emit_json({"remote": remote, "pushed": pushed})
        else:
            typer.echo(f"pushed {len(pushed)} artifacts to {remote}")

    @app.command("pull")
    def pull(
        remote: str = typer.Argument(..., help="Directory or fsspec URL (s3://, gs://, ...)."),
        targets: list[str] | None = typer.Argument(None, help="Stage names or key prefixes."),
        store: Path = STORE_OPT,
        upstream: bool = _UPSTREAM,
        json_: bool = JSON_OPT,
    ) -> None:
        """Fetch artifacts from REMOTE, verifying keys and sha256s before committing."""
        from pipeline.engine.share import pull as do_pull
        from pipeline.engine.store import ArtifactStore

        refs = do_pull(ArtifactStore(store), remote, targets or (), with_upstream=upstream)
        if json_:
            emit_json({"remote": remote, "pulled": [f"{r.stage}/{r.key}" for r in refs]})
        else:
            typer.echo(f"pulled {len(refs)} artifacts from {remote}")
