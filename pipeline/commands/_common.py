"""Options and output helpers shared by the CLI commands (kept light to import)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import typer

__all__ = ["CONFIG_OPT", "JSON_OPT", "SET_OPT", "STORE_OPT", "emit_json", "stderr_console"]

CONFIG_OPT = typer.Option(
    None, "--config", "-c", help="Pipeline config YAML (one section per stage)."
)
SET_OPT = typer.Option(
    None,
    "--set",
    "-s",
    help="Override a config value: section.field=value (lists as a,b). Repeatable.",
)
STORE_OPT = typer.Option(Path("data/store"), "--store", help="Artifact store directory.")
JSON_OPT = typer.Option(False, "--json", help="Print exactly one JSON document on stdout.")


def emit_json(doc: Any) -> None:
    """The one JSON document a `--json` command prints (strict: NaN/inf become null)."""
    from pipeline.formats.strict_json import dumps_strict

    sys.stdout.write(dumps_strict(doc) + "\n")
    sys.stdout.flush()


def stderr_console() -> Any:
    """A rich console on stderr (progress and tables never pollute --json stdout)."""
    from rich.console import Console

    return Console(stderr=True)
