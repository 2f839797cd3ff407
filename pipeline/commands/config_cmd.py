"""`sonarmap config dump|check`: effective defaults, validation of a file."""

from __future__ import annotations

from pathlib import Path

import typer

from pipeline.commands._common import JSON_OPT, SET_OPT, emit_json

__all__ = ["register"]


def register(app: typer.Typer) -> None:
    config_app = typer.Typer(
        help="Inspect and validate pipeline configuration.", no_args_is_help=True
    )
    app.add_typer(config_app, name="config")

    @config_app.command("dump")
    def dump(
        config: Path | None = typer.Option(None, "--config", "-c", help="Config YAML to merge."),
        set_: list[str] | None = SET_OPT,
        json_: bool = JSON_OPT,
    ) -> None:
        """Print the effective config (defaults, then the file, then --set)."""
        from pipeline.engine.config import dump_yaml, load_config
        from pipeline.engine.registry import all_stages, extra_sections

        cfg = load_config(all_stages(), config, set_ or (), extra_sections())
        if json_:
            emit_json(cfg.model_dump(mode="json"))
        else:
            typer.echo(dump_yaml(cfg), nl=False)

    @config_app.command("check")
    def check(file: Path = typer.Argument(..., help="Config YAML to validate.")) -> None:
        """Validate a config file; exit 2 with the offending key on error."""
        from pipeline.engine.config import load_config
        from pipeline.engine.registry import all_stages, extra_sections

        load_config(all_stages(), file, (), extra_sections())
        typer.echo(f"{file}: ok")
