"""Options and output helpers shared by the CLI commands (kept light to import)."""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

if TYPE_CHECKING:
    from sonarmap.pipeline.engine.run.graph import Graph

__all__ = [
    "CONFIG_OPT",
    "JSON_OPT",
    "NO_FIGURES_OPT",
    "SET_OPT",
    "STORE_OPT",
    "WORKERS_OPT",
    "GraphChoice",
    "cli_graph",
    "emit_error_json",
    "emit_json",
    "logged_warnings",
    "stderr_console",
]

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
WORKERS_OPT = typer.Option(
    None,
    "--workers",
    "-j",
    min=1,
    help="Stages computed side by side in worker processes (default: the cores; "
    "1: one after another). The artifacts are the same either way.",
)
# `ctx.meta` is shared by a command's context and its group's, so the group's error handler
# (`cli._ErrorMappingGroup`) sees whether the failed command promised a JSON document.
_JSON_MODE = "sonarmap.json"


def _json_requested(ctx: typer.Context, value: bool) -> bool:
    if value:
        json_requested(ctx)
    return value


def json_requested(ctx: Any) -> None:
    """Promise the failed command's error as its JSON document (`emit_error_json`)."""
    ctx.meta.setdefault(_JSON_MODE, {"emitted": False})


JSON_OPT = typer.Option(
    False,
    "--json",
    callback=_json_requested,
    is_eager=True,  # before the other options: one that fails still gets its document
    help="Print exactly one JSON document on stdout (on failure: its error and exit code).",
)
NO_FIGURES_OPT = typer.Option(
    False,
    "--no-figures",
    help="Skip the figure stages (overlay.png, trajectory.png, errors.png, map_topdown.png,"
    " side_view.png): the map, metrics and report only.",
)


def emit_json(doc: Any) -> None:
    """The one JSON document a `--json` command prints (strict: NaN/inf become null)."""
    from sonarmap.pipeline.formats.strict_json import dumps_strict

    sys.stdout.write(dumps_strict(doc) + "\n")
    sys.stdout.flush()
    import click

    ctx = click.get_current_context(silent=True)
    if ctx is not None and _JSON_MODE in ctx.meta:
        ctx.meta[_JSON_MODE]["emitted"] = True


def emit_error_json(ctx: Any, line: str, exit_code: int) -> None:
    """A failed `--json` command's one document, `{"error": LINE, "exit_code": N}`, so a
    program reading stdout is told why there is no result (the same line as on stderr).
    Nothing when the command took no `--json`, or already printed its document."""
    mode = ctx.meta.get(_JSON_MODE) if ctx is not None else None
    if mode is None or mode["emitted"]:
        return
    mode["emitted"] = True
    from sonarmap.pipeline.formats.strict_json import dumps_strict

    sys.stdout.write(dumps_strict({"error": line, "exit_code": exit_code}) + "\n")
    sys.stdout.flush()


def stderr_console() -> Any:
    """A rich console on stderr (progress and tables never pollute --json stdout)."""
    from rich.console import Console

    return Console(stderr=True)


class GraphChoice:
    """The stage graph of one CLI invocation: named once by the root command (from
    `$SONARMAP_GRAPH`), built when a command first asks for it (`ls` never does).
    A program embedding the CLI passes its own, built graph as the context's `obj`."""

    def __init__(self, spec: str | None, graph: Graph | None = None) -> None:
        self.spec = spec
        self._graph = graph

    def graph(self) -> Graph:
        if self._graph is None:
            from sonarmap.pipeline.engine.run.graph import load_graph
            from sonarmap.pipeline.graph import default_graph

            self._graph = load_graph(self.spec, default_graph)
        return self._graph


def cli_graph(ctx: typer.Context) -> Graph:
    """The graph this invocation runs (the root command's `GraphChoice`); the real
    pipeline's when the command was invoked without the root (its own Typer app).
    `--no-figures` leaves the figure stages out of a run (`RunRequest.figures`), never out
    of the graph: a config with a `figures` section stays valid either way."""
    choice = ctx.find_root().obj
    if not isinstance(choice, GraphChoice):
        choice = GraphChoice(None)
    return choice.graph()


@contextmanager
def logged_warnings() -> Iterator[set[str]]:
    """The warning messages logged meanwhile (the CLI's log handler prints them), so a
    command that also prints a reader's collected warnings prints none twice."""
    seen: set[str] = set()

    class _Seen(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            seen.add(record.getMessage())

    handler = _Seen(logging.WARNING)
    logging.getLogger().addHandler(handler)
    try:
        yield seen
    finally:
        logging.getLogger().removeHandler(handler)
