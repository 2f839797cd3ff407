"""`sonarmap topics FILE|BAGDIR`: topics, types, counts, rates and detected roles."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from sonarmap.pipeline.commands._common import JSON_OPT, emit_json

__all__ = ["register", "topics_report"]


def topics_report(path: Path, options: Any = None) -> dict[str, Any]:
    """What `topics --json` prints: every topic with its role, plus warnings."""
    from sonarmap.pipeline.engine.errors import SourceError
    from sonarmap.pipeline.readers import ReaderOptions, open_source
    from sonarmap.pipeline.readers.mcap_source import McapSource
    from sonarmap.pipeline.readers.roles import detect_roles

    opts = ReaderOptions.from_config(options)
    source = open_source(path, opts.message_definitions)
    if isinstance(source, McapSource):
        # Runs check only the chunks they decompress; the inspection command checks them all.
        source.verify()
    topics = source.topics()
    roles_error = None
    try:
        roles = detect_roles(path, topics, opts, require_pair=False).as_dict()
    except SourceError as err:
        roles, roles_error = {}, str(err)
    by_topic: dict[str, list[str]] = {}
    for role, topic in roles.items():
        by_topic.setdefault(topic, []).append(role)
    firsts = [t.first_ns for t in topics if t.first_ns is not None]
    lasts = [t.last_ns for t in topics if t.last_ns is not None]
    return {
        "path": str(path),
        "format": source.kind,
        "messages": sum(t.count for t in topics),
        "start_ns": min(firsts) if firsts else None,
        "end_ns": max(lasts) if lasts else None,
        "duration_s": (max(lasts) - min(firsts)) * 1e-9 if firsts else 0.0,
        "topics": [
            {
                "topic": t.topic,
                "type": t.msgtype,
                "count": t.count,
                "indexed_count": t.indexed_count,
                "rate_hz": round(t.rate_hz, 6),
                "first_ns": t.first_ns,
                "last_ns": t.last_ns,
                "roles": sorted(by_topic.get(t.topic, [])),
            }
            for t in topics
        ],
        "roles": roles,
        "roles_error": roles_error,
        "warnings": list(source.warnings),
    }


def topics(
    path: Path = typer.Argument(
        ..., help="MCAP file, ROS 2 bag directory, ROS 1 bag or raw Oculus capture."
    ),
    json_: bool = JSON_OPT,
    msg: list[Path] = typer.Option(
        [],
        "--msg",
        help="A .msg (at <package>/msg/<Name>.msg) or .idl file of a custom message type"
        " the recording uses. Repeatable.",
    ),
) -> None:
    """List topics like `ros2 bag info`, with the sonar/navigation roles sonarmap detects."""
    from sonarmap.pipeline.commands._common import logged_warnings

    with logged_warnings() as seen:  # the reader logs some of its warnings itself
        report = topics_report(path, {"message_definitions": tuple(str(m) for m in msg)})
    if json_:
        emit_json(report)
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(
        title=f"{path} ({report['format']}, {report['messages']} messages, "
        f"{report['duration_s']:.2f} s)"
    )
    for col in ("topic", "type", "count", "rate Hz", "span s", "role"):
        table.add_column(col, justify="right" if col in ("count", "rate Hz", "span s") else "left")
    for t in report["topics"]:
        span = (t["last_ns"] - t["first_ns"]) * 1e-9 if t["first_ns"] is not None else 0.0
        count = str(t["count"])
        if t["indexed_count"] is not None and t["indexed_count"] != t["count"]:
            count += f" (index: {t['indexed_count']})"
        table.add_row(
            t["topic"],
            t["type"],
            count,
            f"{t['rate_hz']:.2f}",
            f"{span:.2f}",
            ", ".join(t["roles"]),
        )
    console = Console()
    console.print(table)
    err = Console(stderr=True)
    if report["roles_error"]:
        err.print(f"[yellow]roles:[/] {report['roles_error']}")
    from sonarmap.pipeline.commands._errors import one_line

    for w in report["warnings"]:
        if w not in seen:
            typer.echo(f"warning: {one_line(w)}", err=True)


def register(app: typer.Typer) -> None:
    """Add the `topics` command."""
    app.command("topics")(topics)
