"""MkDocs hook: the CLI, config and column references, generated from the code at every build.

Both pages are built in memory (`on_files`), never committed, so they cannot drift from
the typer app, the pydantic config models and the Arrow schemas they describe. `mkdocs.yml` declares this
file under `hooks:`; `make docs` builds the site with `mkdocs build --strict`.
"""

from __future__ import annotations

import fnmatch
import importlib
import inspect
import json
import re
import types
import typing
from pathlib import Path
from typing import Any

from pydantic import BaseModel

GENERATED = ("reference/cli.md", "reference/config.md", "reference/columns.md")
"""Pages this hook writes (the docs-links test accepts them in the nav)."""

REGISTRY_MODULE = "sonarmap.pipeline.graph"
"""Where `all_stages()` and `extra_sections()` live: the real graph, wired above the
engine."""


def _registry() -> types.ModuleType:
    return importlib.import_module(REGISTRY_MODULE)


def on_files(files: Any, config: Any) -> Any:
    from mkdocs.structure.files import File

    builders = (cli_markdown, config_markdown, columns_markdown)
    for uri, build in zip(GENERATED, builders, strict=True):
        files.append(File.generated(config, uri, content=build()))
    return files


# --- CLI reference -------------------------------------------------------------------


_CODE_SPAN = re.compile(r"(`+)(.+?)\1")


def _text(text: str) -> str:
    """Markdown of plain text: `<` and `>` escaped outside code spans (a code span shows
    them as typed; elsewhere `<directory>` would be read as an HTML tag)."""
    out, last = [], 0
    for match in _CODE_SPAN.finditer(text):
        out.append(text[last : match.start()].replace("<", "&lt;").replace(">", "&gt;"))
        out.append(match.group(0))
        last = match.end()
    out.append(text[last:].replace("<", "&lt;").replace(">", "&gt;"))
    return "".join(out)


def _cell(text: str) -> str:
    """Text safe inside a Markdown table cell: one line, pipes escaped outside code spans
    (Python-Markdown's tables leave a pipe inside a code span alone)."""
    text = _text(" ".join(text.split()))
    parts = re.split(r"(`+.+?`+)", text)
    return "".join(p if p.startswith("`") else p.replace("|", "\\|") for p in parts)


def _code_cell(text: str) -> str:
    """A table cell in a code span: one line, backticks doubled around one in the text
    (Python-Markdown's tables leave a pipe inside a code span alone, and a code span
    shows `<` as it is)."""
    text = " ".join(text.split())
    return f"`` {text} ``" if "`" in text else f"`{text}`"


def _command_sections(cmd: Any, ctx: Any, path: str) -> list[str]:
    """One section per command, then its subcommands. Duck-typed: typer ships its own copy
    of click, whose classes are not `click.Group`."""
    lines = [f"## `{path}`", ""]
    help_text = inspect.cleandoc(cmd.help or "")
    if help_text:
        lines += [_text(help_text), ""]
    lines += ["```text", cmd.get_usage(ctx), "```", ""]
    rows = []
    for param in cmd.get_params(ctx):
        record = param.get_help_record(ctx)
        if record is None:
            continue
        names, help_line = record
        rows.append(f"| `{names}` | {_cell(help_line)} |")
    if rows:
        lines += ["| option | meaning |", "|---|---|", *rows, ""]
    if hasattr(cmd, "list_commands"):
        for name in cmd.list_commands(ctx):
            sub = cmd.get_command(ctx, name)
            if sub is None or sub.hidden:
                continue
            sub_ctx = sub.context_class(sub, info_name=name, parent=ctx)
            lines += _command_sections(sub, sub_ctx, f"{path} {name}")
    return lines


def cli_markdown() -> str:
    import typer

    from sonarmap.pipeline.cli import app

    root = typer.main.get_command(app)
    ctx = root.context_class(root, info_name="sonarmap")
    lines = [
        "# CLI reference",
        "",
        "Generated from the typer app (`sonarmap.pipeline.cli`) when the site is built;",
        "`sonarmap COMMAND --help` prints the same text.",
        "",
        "Every reporting command takes `--json` and then prints exactly one JSON document",
        "on stdout. Exit codes: 0 success, 2 bad input, 1 a bug"
        " ([exit codes](../exit-codes.md)).",
        "",
    ]
    lines += _command_sections(root, ctx, "sonarmap")
    return "\n".join(lines) + "\n"


# --- config reference ----------------------------------------------------------------

_ATTR_LINE = re.compile(r"^(\s+)([\w*, ]+):\s*(.*)$")


def _attribute_docs(model: type[BaseModel]) -> dict[str, str]:
    """`Attributes:` entries of a Google-style class docstring, by field-name pattern
    (an entry may name several fields, `a, b:`, or a glob, `*_mount_xyz_m:`)."""
    doc = inspect.cleandoc(model.__doc__ or "")
    if "Attributes:" not in doc:
        return {}
    body = doc.split("Attributes:", 1)[1].splitlines()
    entries: dict[str, str] = {}
    current: list[str] | None = None
    indent = None
    for line in body:
        if not line.strip():
            continue
        match = _ATTR_LINE.match(line)
        if match and (indent is None or len(match.group(1)) == indent):
            indent = len(match.group(1))
            current = [match.group(3)]
            for name in match.group(2).split(","):
                entries[name.strip()] = current  # type: ignore[assignment]
        elif current is not None and indent is not None and len(line) - len(line.lstrip()) > indent:
            current.append(line.strip())
        elif indent is not None and len(line) - len(line.lstrip()) < indent:
            break
    return {name: " ".join(parts) for name, parts in entries.items()}  # type: ignore[arg-type]


def _describe(name: str, field: Any, attrs: dict[str, str]) -> str:
    if field.description:
        return str(field.description)
    for pattern, text in attrs.items():
        if pattern == name or fnmatch.fnmatchcase(name, pattern):
            return text
    return ""


def _type_name(annotation: Any) -> str:
    if isinstance(annotation, type) and not typing.get_args(annotation):
        return annotation.__name__
    text = repr(annotation)
    text = re.sub(r"<class '([\w.]+)'>", lambda m: m.group(1).rsplit(".", 1)[-1], text)
    text = re.sub(r"\b(?:[a-z_]\w*\.)+([A-Za-z_]\w*)", r"\1", text)
    return re.sub(r"Annotated\[(\w+), [^\]]*\]", r"\1", text)


def _bounds(field: Any) -> str:
    marks = []
    for item in field.metadata:
        for attr, sign in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
            value = getattr(item, attr, None)
            if value is not None:
                marks.append(f"{sign} {value}")
        for attr, label in (("min_length", "len >="), ("max_length", "len <=")):
            value = getattr(item, attr, None)
            if value is not None:
                marks.append(f"{label} {value}")
    return ", ".join(marks)


def _default(field: Any) -> str:
    if field.default_factory is not None:
        value = field.default_factory()
    elif field.is_required():
        return "(required)"
    else:
        value = field.default
    try:
        text = json.dumps(value, default=lambda v: v.model_dump(mode="json"))
    except TypeError:
        text = repr(value)
    # A default taken from the building machine (a cache directory) is shown for anyone.
    text = text.replace(str(Path.home()), "~")
    return text if len(text) <= 60 else text[:57] + "..."


def _nested_models(annotation: Any) -> list[type[BaseModel]]:
    found = []
    stack = [annotation]
    while stack:
        item = stack.pop()
        if isinstance(item, type) and issubclass(item, BaseModel):
            found.append(item)
        else:
            stack.extend(typing.get_args(item))
    return found


def _model_section(title: str, model: type[BaseModel], seen: dict[type, str]) -> list[str]:
    """A section per config model; a model met again (the `training` section's own
    `keyframes`) points to its first section instead of repeating it."""
    seen[model] = title
    doc = inspect.cleandoc(model.__doc__ or "").split("Attributes:", 1)[0].strip()
    lines = [f"## `{title}`", "", f"`{model.__module__}.{model.__qualname__}`", ""]
    if doc:
        lines += [_text(doc), ""]
    attrs = _attribute_docs(model)
    nested: list[tuple[str, type[BaseModel]]] = []
    if model.model_fields:
        lines += ["| key | type | default | bounds | meaning |", "|---|---|---|---|---|"]
    for name, field in model.model_fields.items():
        subs = _nested_models(field.annotation)
        if isinstance(field.annotation, type) and field.annotation in seen:
            default = f"the keys of `{seen[field.annotation]}`"
        elif isinstance(field.annotation, type) and subs:
            default = f"the keys of `{title}.{name}` below"
        else:
            default = _code_cell(_default(field))
        lines.append(
            f"| `{name}` | {_code_cell(_type_name(field.annotation))} | {default}"
            f" | {_cell(_bounds(field))} | {_cell(_describe(name, field, attrs))} |"
        )
        nested += [(f"{title}.{name}", sub) for sub in subs if sub not in seen]
    lines.append("")
    for sub_title, sub in nested:
        if sub not in seen:
            lines += _model_section(sub_title, sub, seen)
    return lines


def config_markdown() -> str:
    registry = _registry()
    lines = [
        "# Config reference",
        "",
        "Generated from the pydantic models of every stage with a config section, and the",
        "engine's own sections, when the site is built. `sonarmap config dump` prints the",
        "same defaults as YAML; `sonarmap config check FILE` validates a file against them.",
        "Override any key with `--set section.key=value` (lists as `a,b`).",
        "",
    ]
    seen: dict[type, str] = {}
    for stage in registry.all_stages():
        lines += _model_section(stage.name, stage.config, seen)
    for name, model in registry.extra_sections().items():
        lines += _model_section(name, model, seen)
    return "\n".join(lines) + "\n"


# --- column reference ----------------------------------------------------------------


def columns_markdown() -> str:
    import pkgutil

    import pyarrow as pa

    import sonarmap.schemas as schemas

    lines = [
        "# Column reference",
        "",
        "Every Arrow schema of `sonarmap.schemas`, generated when the site is built: the",
        "columns of the Parquet files the stages write. Units are in the names; time is",
        "int64 nanoseconds (`t_ns`).",
        "",
    ]
    modules = sorted(pkgutil.iter_modules(schemas.__path__), key=lambda i: i.name)
    loaded = [importlib.import_module(f"sonarmap.schemas.{info.name}") for info in modules]
    # A schema that several modules hold (a re-export) is listed once, under the first
    # module in alphabetical order that holds it.
    owner: dict[int, str] = {}
    for module in loaded:
        for name, value in vars(module).items():
            if isinstance(value, pa.Schema) and not name.startswith("_"):
                owner.setdefault(id(value), module.__name__)
    for info, module in zip(modules, loaded, strict=True):
        found = [
            (name, value)
            for name, value in sorted(vars(module).items())
            if isinstance(value, pa.Schema)
            and not name.startswith("_")
            and owner[id(value)] == module.__name__
        ]
        if not found:
            continue
        doc = inspect.cleandoc(module.__doc__ or "").split("\n\n", 1)[0]
        lines += [f"## `sonarmap.schemas.{info.name}`", "", _cell(doc), ""]
        for name, schema in found:
            lines += [f"### `{name}`", "", "| column | type | nullable |", "|---|---|---|"]
            lines += [
                f"| `{f.name}` | {_code_cell(str(f.type))} | {'yes' if f.nullable else 'no'} |"
                for f in schema
            ]
            lines.append("")
    return "\n".join(lines) + "\n"
