"""The `sonarmap` command line (typer). Known errors become one line and exit 2 (or 1)."""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import inspect
import logging
import os
import signal
import sys
import time
from types import FrameType
from typing import NoReturn

import click
import typer
from typer.core import TyperGroup

from sonarmap.pipeline import __version__
from sonarmap.pipeline.commands import COMMAND_MODULES
from sonarmap.pipeline.commands._common import GraphChoice, emit_error_json, json_requested
from sonarmap.pipeline.commands._errors import MAX_LINE_CHARS, one_line, os_error_line
from sonarmap.pipeline.engine.errors import PipelineError
from sonarmap.pipeline.engine.run.abandon import abandon_open_runs
from sonarmap.pipeline.engine.text import scrub_userinfo

__all__ = ["app", "main"]


class _ErrorMappingGroup(TyperGroup):
    """Turns known `PipelineError`s into one line on stderr and their exit code (2 or 1),
    and an `OSError` naming a file into `error: PATH: reason` and exit 2."""

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        """The top level's own options (`sonarmap --bogus`): one line, as a command's."""
        try:
            rest = super().parse_args(ctx, args)
            ctx.meta[_COMMAND_ARGS] = list(rest)  # the command's own, for its error handler
            return rest
        except Exception as err:
            if _usage_error(err) and type(err).__name__ != "NoArgsIsHelpError":
                _fail(err.format_message() + " (sonarmap --help)", 2, err)  # type: ignore[attr-defined]
            raise

    def invoke(self, ctx: click.Context) -> object:  # type: ignore[override]
        try:
            return super().invoke(ctx)  # type: ignore[arg-type]
        except PipelineError as err:
            _fail(str(err), err.exit_code, err, ctx)
        except BrokenPipeError:
            # The reader of stdout left (`sonarmap topics f.mcap | head`): click's own
            # handler ends quietly with exit 1, not an `internal error` line.
            raise
        except OSError as err:
            # A path the user named (recording, --out, --store) that cannot be read or
            # written is bad input; an OSError naming no file is a bug (below).
            line = os_error_line(err)
            if line is None:
                _internal(err, ctx)
            _fail(line, 2, err, ctx)
        except Exception as err:  # the last resort: one line, credentials scrubbed
            if _usage_error(err):
                # A bad option value or an unknown option of a command: one line, as every
                # other error (click's framed box took 5-12 lines, 12 at 80 columns). An
                # unknown option stops parsing before `--json` is read: look for it.
                if "--json" in ctx.meta.get(_COMMAND_ARGS, ()):
                    json_requested(ctx)
                command = ctx.invoked_subcommand or ""
                hint = f" (sonarmap {command} --help)".replace("  ", " ")
                _fail(err.format_message() + hint, 2, err, ctx)  # type: ignore[attr-defined]
            if _cli_flow(err):
                raise
            _internal(err, ctx)


_COMMAND_ARGS = "sonarmap.command_args"


def _cli_flow(err: BaseException) -> bool:
    """Whether `err` is how click or typer end a command (help, usage error, exit code);
    typer may carry its own copy of click (`typer._click`), so it is told by module."""
    return any(
        c.__module__.endswith(("click.exceptions", "typer.exceptions")) for c in type(err).__mro__
    )


def _usage_error(err: BaseException) -> bool:
    """Whether `err` is click's usage error (a bad value, a missing argument, an unknown
    option), from whichever copy of click raised it."""
    return any(
        c.__name__ == "UsageError" and c.__module__.endswith("click.exceptions")
        for c in type(err).__mro__
    )


def _internal(err: BaseException, ctx: click.Context | None = None) -> NoReturn:
    """A bug or a library's unexpected error: one line (no traceback, which would echo
    the URLs and secrets in its frames' text) and exit 1; `-v` logs the traceback,
    scrubbed the same way."""
    logging.getLogger("sonarmap").info("internal error", exc_info=err)
    _fail(f"internal error: {type(err).__name__}: {err}", 1, err, ctx)


def _fail(
    message: str, code: int, cause: BaseException, ctx: click.Context | None = None
) -> NoReturn:
    """Print `error: MESSAGE` as one safe line on stderr and exit with `code` (the whole
    line within the README's 400 characters, any URL's user-info removed); a command run
    with `--json` also prints the line as its JSON document."""
    prefix = "error: "
    line = one_line(scrub_userinfo(message), MAX_LINE_CHARS - len(prefix))
    typer.echo(prefix + line, err=True)
    emit_error_json(ctx, line, code)
    raise typer.Exit(code) from cause


app = typer.Typer(
    name="sonarmap",
    cls=_ErrorMappingGroup,
    help="Predictive 3D sonar mapping: a staged, cached MCAP/Parquet pipeline.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"sonarmap {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    ctx: typer.Context,
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
    verbose: int = typer.Option(0, "--verbose", "-v", count=True, help="More logging on stderr."),
) -> None:
    """sonarmap: orthogonal imaging-sonar pair -> 3D maps (McConnell & Englot, ICRA 2021)."""
    # The one place the alternative graph's variable is read (`registry.GRAPH_ENV`): the
    # graph is built from it once and handed to every command through the context.
    from sonarmap.pipeline.engine.run.graph import GRAPH_ENV

    if not isinstance(ctx.obj, GraphChoice):  # else: given by a program embedding the CLI
        ctx.obj = GraphChoice(os.environ.get(GRAPH_ENV))
    level = logging.WARNING - 10 * min(verbose, 2)
    logging.basicConfig(level=level, stream=sys.stderr)
    for handler in logging.getLogger().handlers:
        if type(handler) is logging.StreamHandler:  # ours, not a test harness's capture
            handler.setFormatter(_UserFormatter(detailed=verbose > 0))
            if verbose == 0 and not any(isinstance(f, _OrphanTasks) for f in handler.filters):
                handler.addFilter(_OrphanTasks())


class _OrphanTasks(logging.Filter):
    """Drop asyncio's "Task exception was never retrieved": a remote library's requests
    still in flight when the first one failed (a connection dropped mid-push); the failure
    itself is the command's one `error:` line, and `-v` shows them."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not (record.name == "asyncio" and "never retrieved" in str(record.msg))


class _UserFormatter(logging.Formatter):
    """Warnings as the one-line `warning: ...` of docs/exit-codes.md (user data escaped); with -v, the
    level and logger name as well, for developers."""

    def __init__(self, detailed: bool) -> None:
        super().__init__("%(levelname)s %(name)s: %(message)s" if detailed else None)
        self.detailed = detailed

    def format(self, record: logging.LogRecord) -> str:
        if self.detailed:
            return scrub_userinfo(super().format(record))
        prefix = f"{record.levelname.lower()}: "
        return prefix + one_line(scrub_userinfo(record.getMessage()), MAX_LINE_CHARS - len(prefix))


def reflowed(doc: str) -> str:
    """A help text's paragraphs each on one line (rich keeps a docstring's line breaks, so
    at 80 columns a paragraph wrapped at 88 broke mid-sentence); blank lines kept."""
    paragraphs = inspect.cleandoc(doc).split("\n\n")
    return "\n\n".join(" ".join(p.split()) for p in paragraphs)


for _name in COMMAND_MODULES:
    if importlib.util.find_spec(f"sonarmap.pipeline.commands.{_name}") is not None:
        importlib.import_module(f"sonarmap.pipeline.commands.{_name}").register(app)
for _command in app.registered_commands:
    if _command.help is None and _command.callback is not None and _command.callback.__doc__:
        _command.help = reflowed(_command.callback.__doc__)


def main() -> None:
    """Console-script entry point. A SIGTERM (`kill`, a batch scheduler's stop) or a SIGHUP
    (the terminal closed) unwinds as Ctrl-C does: the run's lease is released, its
    unfinished commits are removed and its worker processes end, where the default action
    would kill this process alone."""
    signal.signal(signal.SIGTERM, _terminated)
    # A closed terminal (SIGHUP) stops the command as `kill` does; `nohup` keeps it going.
    if signal.getsignal(signal.SIGHUP) is not signal.SIG_IGN:
        signal.signal(signal.SIGHUP, _terminated)
    try:
        app()
    except SystemExit as stop:
        if stop.code in _INTERRUPTED_STATUSES:
            _leave_interrupted(stop.code)
        raise


_INTERRUPTED_STATUSES = (128 + signal.SIGINT, 128 + signal.SIGTERM, 128 + signal.SIGHUP)
"""Ctrl-C (typer's 130), SIGTERM and SIGHUP (`_terminated`'s 143 and 129)."""


def _terminated(signum: int, _frame: FrameType | None) -> NoReturn:
    if signum == signal.SIGHUP:
        # The terminal is gone: writing to it would fail (EIO) while the run unwinds.
        # Output sent to a file still gets the closing lines.
        devnull = os.open(os.devnull, os.O_RDWR)
        for fd in (0, 1, 2):
            if os.isatty(fd):
                os.dup2(devnull, fd)
    raise SystemExit(128 + signum)


def _leave_interrupted(status: int) -> NoReturn:
    """End an interrupted command with `status`, skipping the C++ static destructors.

    An interrupt abandons the stage running in this process on a daemon thread, with the
    Open3D tensors it holds. At C++ exit Open3D's memory statistics find them, print a
    leak report on stdout (into a `--json` document) and call `exit(1)`, so Ctrl-C
    exited 1 whenever evaluation or inference was running. By now the command has
    unwound (lease released, unfinished commits removed, workers ended); Python's own
    exit handlers still run, then the process ends without the C++ teardown.
    """
    import atexit

    abandon_open_runs()  # those an interrupt left on other threads (`follow`'s updates)
    _end_child_processes()  # multiprocessing's exit handler would wait for them
    run_exit_functions = getattr(atexit, "_run_exitfuncs", None)
    if run_exit_functions is not None:
        run_exit_functions()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a reader that left, a closed stream
            stream.flush()
    os._exit(status)


def _end_child_processes(grace_s: float = 2.0) -> None:
    """Worker processes still alive after an interrupt (each unwinds on SIGTERM, then
    ends) are ended within `grace_s`, then killed."""
    multiprocessing = sys.modules.get("multiprocessing")
    if multiprocessing is None:
        return
    children = multiprocessing.active_children()
    for child in children:
        child.terminate()
    deadline = time.monotonic() + grace_s
    for child in children:
        child.join(timeout=max(0.0, deadline - time.monotonic()))
        if child.is_alive():
            child.kill()
