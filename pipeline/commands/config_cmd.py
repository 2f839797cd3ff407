"""`sonarmap config dump|check`: effective defaults, validation of a file."""

from __future__ import annotations

from pathlib import Path

import typer

from sonarmap.pipeline.commands._common import JSON_OPT, SET_OPT, cli_graph, emit_json

__all__ = ["check", "dump", "register"]


def dump(
    ctx: typer.Context,
    config: Path | None = typer.Option(None, "--config", "-c", help="Config YAML to merge."),
    set_: list[str] | None = SET_OPT,
    json_: bool = JSON_OPT,
) -> None:
    """Print the effective config (defaults, then the file, then --set)."""
    from sonarmap.pipeline.engine.config.load import dump_yaml, load_config, user_settings

    graph = cli_graph(ctx)
    cfg = load_config(graph.config_stages, config, set_ or (), graph.extra_sections)
    if json_:
        emit_json(user_settings(cfg))
    else:
        typer.echo(dump_yaml(cfg), nl=False)


def check(
    ctx: typer.Context, file: Path = typer.Argument(..., help="Config YAML to validate.")
) -> None:
    """Validate a config file; exit 2 with the offending key on error."""
    from sonarmap.pipeline.commands._config_references import check_references
    from sonarmap.pipeline.engine.config.load import load_config

    graph = cli_graph(ctx)
    config = load_config(graph.config_stages, file, (), graph.extra_sections)
    check_references(config)  # what it names outside itself, read as a run would
    typer.echo(f"{file}: ok")


def register(app: typer.Typer) -> None:
    config_app = typer.Typer(
        help="Inspect and validate pipeline configuration.", no_args_is_help=True
    )
    app.add_typer(config_app, name="config")
    config_app.command("dump")(dump)
    config_app.command("check")(check)
