"""Every YAML sonarmap reads (configs, `--set` values, annotations, bag metadata, scenes).

One bounded loader, built on PyYAML's SafeLoader, so a small hostile file can never
make sonarmap build something large or recurse without end:

- aliases and anchors are refused (not expanded under a cap: no config or annotation
  file needs them, and refusing is the only rule that bounds every expansion shape);
- a mapping key given twice is refused (the last one silently winning loses data);
- nesting deeper than `MAX_DEPTH` is refused while composing, before Python recursion;
- an integer scalar longer than `MAX_INT_CHARS` is refused before `int()` sees it;
- a document of more than its node cap (`CONFIG_MAX_NODES` by default) is refused while
  composing, so the time spent on a file is bounded whatever its shape;
- a file must be a regular file no larger than its cap (`user_files.read_user_file`:
  `fstat` after a non-blocking open, at most cap+1 bytes read), so `/dev/zero` or a FIFO
  is refused.

Each refusal happens before the document is constructed and is one line naming the file
(or `--set KEY`) and the 1-based line:column. PyYAML's own messages span 4-7 lines with
an excerpt of the file; they are reduced to the same one-line form.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError
from yaml.composer import Composer
from yaml.constructor import SafeConstructor
from yaml.resolver import Resolver

from sonarmap.pipeline.engine.config.validation import short
from sonarmap.pipeline.engine.errors import PipelineError
from sonarmap.pipeline.engine.text import one_line

ModelT = TypeVar("ModelT", bound=BaseModel)

__all__ = [
    "CONFIG_MAX_BYTES",
    "CONFIG_MAX_NODES",
    "MAX_DEPTH",
    "MAX_INT_CHARS",
    "YamlRefused",
    "load_yaml_text",
    "read_model",
    "read_yaml",
    "yaml_error_line",
]

CONFIG_MAX_BYTES = 1 << 20
"""Largest config, scene or metadata file read (a real one is a few KB)."""

MAX_DEPTH = 64
"""Deepest nesting of mappings and sequences (a config is 3-4 levels deep)."""

MAX_INT_CHARS = 40
"""Longest integer scalar (a nanosecond time has 19 digits)."""

CONFIG_MAX_NODES = 50_000
"""Most scalars, mappings and sequences in a config (one has a few hundred): with the
byte cap, this bounds the time to parse or refuse, whatever the document's shape."""


class YamlRefused(yaml.MarkedYAMLError):
    """A document the bounded loader refuses (alias, duplicate key, depth, huge int)."""


def _at(mark: Any) -> str:
    return f"line {mark.line + 1}:{mark.column + 1}"


try:  # libyaml's event parser is ~7x faster than PyYAML's pure-Python one
    from yaml._yaml import CParser as _EventSource
except ImportError:  # pragma: no cover - PyYAML built without libyaml
    from yaml.parser import Parser
    from yaml.reader import Reader
    from yaml.scanner import Scanner

    class _EventSource(Reader, Scanner, Parser):  # type: ignore[no-redef]
        def __init__(self, stream: str) -> None:
            Reader.__init__(self, stream)
            Scanner.__init__(self)
            Parser.__init__(self)


class BoundedLoader(_EventSource, Composer, SafeConstructor, Resolver):
    """SafeLoader that refuses aliases, anchors, duplicate keys, deep nesting, huge ints.

    Events come from libyaml when available; composing (where the bounds are enforced)
    and constructing are PyYAML's Python code, so libyaml's own composer is bypassed.
    """

    # CParser implements these natively; the Python composer's versions call compose_node.
    check_node = Composer.check_node
    get_node = Composer.get_node
    get_single_node = Composer.get_single_node
    compose_document = Composer.compose_document
    compose_scalar_node = Composer.compose_scalar_node
    compose_sequence_node = Composer.compose_sequence_node
    compose_mapping_node = Composer.compose_mapping_node

    def __init__(self, stream: str, max_nodes: int = CONFIG_MAX_NODES) -> None:
        _EventSource.__init__(self, stream)
        Composer.__init__(self)
        SafeConstructor.__init__(self)
        Resolver.__init__(self)
        self._depth = 0
        self._nodes = 0
        self._max_nodes = max_nodes

    def compose_node(self, parent: Any, index: Any) -> Any:
        event: Any = self.peek_event()
        mark: Any = event.start_mark
        if isinstance(event, yaml.AliasEvent):
            raise YamlRefused(
                problem=f"alias *{one_line(str(event.anchor), 40)} refused (aliases are not supported)",
                problem_mark=mark,
            )
        if getattr(event, "anchor", None) is not None:
            raise YamlRefused(
                problem=f"anchor &{one_line(str(event.anchor), 40)} refused (anchors are not supported)",
                problem_mark=event.start_mark,
            )
        self._nodes += 1
        if self._nodes > self._max_nodes:
            raise YamlRefused(
                problem=f"more than {self._max_nodes} values (a YAML document this large is"
                " not a sonarmap input)",
                problem_mark=mark,
            )
        nested = isinstance(event, yaml.MappingStartEvent | yaml.SequenceStartEvent)
        if nested:
            self._depth += 1
            if self._depth > MAX_DEPTH:
                raise YamlRefused(
                    problem=f"nested deeper than {MAX_DEPTH} levels",
                    problem_mark=event.start_mark,
                )
        try:
            return Composer.compose_node(self, parent, index)
        finally:
            if nested:
                self._depth -= 1

    def construct_mapping(self, node: Any, deep: bool = False) -> dict[Any, Any]:
        # Duplicates are found on the constructed keys, so `1` and `0x1` count as one.
        seen: dict[Any, Any] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                first = seen.setdefault(key, key_node)
            except TypeError:  # an unhashable key: SafeConstructor reports it below
                continue
            if first is not key_node:
                raise YamlRefused(
                    context=f"first at {_at(first.start_mark)}",
                    context_mark=None,
                    problem=f"duplicate key {short(key, 60)}",
                    problem_mark=key_node.start_mark,
                )
        return SafeConstructor.construct_mapping(self, node, deep=deep)

    def construct_yaml_int(self, node: Any) -> int:
        if len(node.value) > MAX_INT_CHARS:
            raise YamlRefused(
                problem=f"integer of {len(node.value)} characters refused "
                f"(at most {MAX_INT_CHARS}): {short(node.value, 20)}",
                problem_mark=node.start_mark,
            )
        return SafeConstructor.construct_yaml_int(self, node)


BoundedLoader.add_constructor(  # type: ignore[type-var]
    "tag:yaml.org,2002:int", BoundedLoader.construct_yaml_int
)


def yaml_error_line(err: yaml.YAMLError) -> str:
    """`line L:C: problem (context at line L:C)` of a PyYAML error, 1-based, one line."""
    problem = getattr(err, "problem", None) or str(err).splitlines()[0]
    mark = getattr(err, "problem_mark", None)
    text = f"{_at(mark)}: {problem}" if mark is not None else str(problem)
    context, context_mark = getattr(err, "context", None), getattr(err, "context_mark", None)
    if context:
        text += f" ({context}" + (f" at {_at(context_mark)})" if context_mark else ")")
    return one_line(text)


def load_yaml_text(
    text: str,
    where: str,
    what: str,
    error: type[PipelineError],
    max_nodes: int = CONFIG_MAX_NODES,
) -> Any:
    """Parse YAML text with the bounded loader.

    Args:
        where: what names the text in messages (a path, `--set KEY`).
        what: what the text is ("config", "annotations").
        error: the error type to raise.
        max_nodes: the most scalars, mappings and sequences accepted.

    Raises:
        error: refused or not YAML; one line naming `where` and the line:column.
    """
    loader = BoundedLoader(text, max_nodes)
    try:
        return loader.get_single_data()
    except YamlRefused as err:
        raise error(f"{where}: {what} refused ({yaml_error_line(err)})") from err
    except yaml.YAMLError as err:
        raise error(f"{where}: {what} is not valid YAML ({yaml_error_line(err)})") from err
    except RecursionError as err:  # defence in depth: MAX_DEPTH stops this long before
        raise error(f"{where}: {what} is nested too deeply") from err
    finally:
        loader.dispose()


def _read_capped(path: Path, what: str, error: type[PipelineError], max_bytes: int) -> bytes:
    """The bytes of a regular file of at most `max_bytes` (`user_files.read_user_file`)."""
    from sonarmap.pipeline.engine.user_files import read_user_file

    return read_user_file(path, what, error, max_bytes)


def read_yaml(
    path: Path,
    what: str,
    error: type[PipelineError],
    max_bytes: int = CONFIG_MAX_BYTES,
    max_nodes: int = CONFIG_MAX_NODES,
) -> Any:
    """Parse a UTF-8 YAML file with the bounded loader.

    Args:
        path: the file.
        what: what the file is, for messages ("config", "bag metadata").
        error: the error type to raise (ConfigError, SourceError).
        max_bytes: the largest file accepted.
        max_nodes: the most scalars, mappings and sequences accepted.

    Raises:
        error: not a regular file, too large, unreadable, not UTF-8, not YAML, or refused
            by the loader's bounds; one line naming the file.
    """
    where = one_line(str(path))
    data = _read_capped(path, what, error, max_bytes)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise error(
            f"{where}: {what} is not UTF-8 text (byte {err.start} is {err.object[err.start]:#04x})"
        ) from err
    return load_yaml_text(text, where, what, error, max_nodes)


def read_model(
    path: Path,
    what: str,
    model: type[ModelT],
    error: type[PipelineError],
    describe: Callable[[ValidationError], str],
    not_a_mapping: str,
    max_bytes: int = CONFIG_MAX_BYTES,
    max_nodes: int = CONFIG_MAX_NODES,
    context: dict[str, Any] | None = None,
) -> ModelT:
    """A YAML mapping validated as `model`; every fault is one `error` line.

    Args:
        describe: the one-line message of a validation error.
        not_a_mapping: the message when the document is not a mapping.
        context: pydantic validation context (e.g. the class table, `sonarmap.schemas.annotations`).
    """
    raw = read_yaml(path, what, error, max_bytes, max_nodes)
    if not isinstance(raw, dict):
        raise error(f"{one_line(str(path))}: {not_a_mapping}, got {type(raw).__name__}")
    try:
        return model.model_validate(raw, context=context)
    except ValidationError as err:
        raise error(one_line(describe(err))) from err
