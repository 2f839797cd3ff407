"""YAML files read by the engine (configs, bag metadata, annotations): one-line errors.

PyYAML's own messages span 4-7 lines with an excerpt of the file; the CLI contract is
one line, so a parse error becomes `file: ... (line L:C: problem)`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from pipeline.engine.errors import PipelineError

ModelT = TypeVar("ModelT", bound=BaseModel)

__all__ = ["read_model", "read_yaml", "yaml_error_line"]


def _at(mark: Any) -> str:
    return f"line {mark.line + 1}:{mark.column + 1}"


def yaml_error_line(err: yaml.YAMLError) -> str:
    """`line L:C: problem (context at line L:C)` of a PyYAML error, 1-based, one line."""
    problem = getattr(err, "problem", None) or str(err).splitlines()[0]
    mark = getattr(err, "problem_mark", None)
    text = f"{_at(mark)}: {problem}" if mark is not None else problem
    context, context_mark = getattr(err, "context", None), getattr(err, "context_mark", None)
    if context:
        text += f" ({context}" + (f" at {_at(context_mark)})" if context_mark else ")")
    return text


def read_yaml(path: Path, what: str, error: type[PipelineError]) -> Any:
    """Parse a UTF-8 YAML file with `yaml.safe_load`.

    Args:
        path: the file.
        what: what the file is, for messages ("config", "bag metadata").
        error: the error type to raise (ConfigError, SourceError).

    Raises:
        error: unreadable, not UTF-8, or not YAML; one line naming the file.
    """
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as err:
        raise error(f"{path}: cannot read {what} ({err.strerror})") from err
    except UnicodeDecodeError as err:
        raise error(
            f"{path}: {what} is not UTF-8 text (byte {err.start} is {err.object[err.start]:#04x})"
        ) from err
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise error(f"{path}: {what} is not valid YAML ({yaml_error_line(err)})") from err


def read_model(
    path: Path,
    what: str,
    model: type[ModelT],
    error: type[PipelineError],
    describe: Callable[[ValidationError], str],
    not_a_mapping: str,
) -> ModelT:
    """A YAML mapping validated as `model`; every fault is one `error` line.

    Args:
        describe: the one-line message of a validation error.
        not_a_mapping: the message when the document is not a mapping.
    """
    raw = read_yaml(path, what, error)
    if not isinstance(raw, dict):
        raise error(f"{path}: {not_a_mapping}, got {type(raw).__name__}")
    try:
        return model.model_validate(raw)
    except ValidationError as err:
        raise error(describe(err)) from err
