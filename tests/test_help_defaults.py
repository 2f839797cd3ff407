"""Every command's --help shows defaults as names or project-relative paths."""

from __future__ import annotations

import sys
from pathlib import Path

import click
import typer
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app

ROOT = Path(__file__).resolve().parent.parent


def _commands(group: click.Command, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out = []
    for name, cmd in getattr(group, "commands", {}).items():
        out.append((*prefix, name))
        if isinstance(getattr(cmd, "commands", None), dict):
            out += _commands(cmd, (*prefix, name))
    return out


def test_help_never_shows_an_install_path() -> None:
    commands = _commands(typer.main.get_command(app))  # type: ignore[arg-type]
    assert ("simulate",) in commands and ("config", "dump") in commands
    runner = CliRunner()
    for words in commands:
        res = runner.invoke(app, [*words, "--help"], env={"COLUMNS": "400"})
        assert res.exit_code == 0, (words, res.output)
        for install in {str(ROOT), sys.prefix, "site-packages"}:
            assert install not in res.output, (words, install)
    simulate = runner.invoke(app, ["simulate", "--help"], env={"COLUMNS": "400"}).output
    assert "[default: marina]" in simulate
