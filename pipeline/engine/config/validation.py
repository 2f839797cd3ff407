"""One-line config validation errors: `section.field = value: problem (allowed range)`.

The allowed range is read from the field's own bounds (`gt`, `ge`, `lt`, `le`), so the
message never restates a default or a limit by hand.
"""

from __future__ import annotations

import reprlib
import types
import typing
from collections.abc import Sequence
from typing import Annotated, Any

from pydantic import BaseModel, ValidationError

from sonarmap.pipeline.engine.text import one_line

__all__ = ["MAX_QUOTE_CHARS", "allowed_range", "short", "validation_message"]

MAX_QUOTE_CHARS = 60
"""Longest quote of a bad value in a message (a value may be megabytes long)."""

MAX_MESSAGE_CHARS = 300
"""Longest validation problem text (a validator may embed the value it rejects)."""


def short(value: Any, limit: int = MAX_QUOTE_CHARS) -> str:
    """A repr of `value` of at most `limit` characters (with an ellipsis): a quote of a bad
    value. `reprlib` elides long strings and containers while rendering, so a huge value
    is never rendered whole."""
    if isinstance(value, int) and value.bit_length() > 4 * limit:
        return f"<integer of {value.bit_length()} bits>"
    quoter = reprlib.Repr()
    quoter.maxstring = quoter.maxother = quoter.maxlong = limit
    quoter.maxlist = quoter.maxtuple = quoter.maxset = quoter.maxdict = 6
    try:
        text = quoter.repr(value)
    except ValueError:  # an int nested in a container past Python's 4,300-digit limit
        return f"<{type(value).__name__}>"
    return one_line(text, limit)


def _unwrap(annotation: Any) -> tuple[Any, list[Any]]:
    """(inner type, Annotated metadata) with Optional removed."""
    metadata: list[Any] = []
    while True:
        origin = typing.get_origin(annotation)
        if origin is Annotated:
            annotation, *extra = typing.get_args(annotation)
            metadata.extend(extra)
        elif origin in (typing.Union, types.UnionType):
            args = [a for a in typing.get_args(annotation) if a is not type(None)]
            if len(args) != 1:
                return annotation, metadata
            annotation = args[0]
        else:
            return annotation, metadata


def _constraints(model: type[BaseModel], loc: Sequence[int | str]) -> list[Any]:
    """The bound metadata of the field (or tuple element) at `loc`; [] when unknown."""
    current: Any = model
    metadata: list[Any] = []
    for part in loc:
        if isinstance(current, type) and issubclass(current, BaseModel):
            field = current.model_fields.get(str(part))
            if field is None:
                return []
            current, metadata = _unwrap(field.annotation)
            metadata = [*field.metadata, *metadata]
        elif isinstance(part, int) and typing.get_origin(current) in (tuple, list):
            args = typing.get_args(current)
            element = args[0] if len(args) == 1 or args[1:] == (...,) else args[part]
            current, metadata = _unwrap(element)
        else:
            return []
    return metadata


def allowed_range(model: type[BaseModel], loc: Sequence[int | str]) -> str | None:
    """`> 0 and <= 1000` for a bounded number at `loc` (None when it has no bounds)."""
    words = []
    items = _constraints(model, loc)
    # An element type `Annotated[float, Field(...)]` carries a FieldInfo holding the bounds.
    items = [m for item in items for m in getattr(item, "metadata", [item])]
    for item in items:
        for attr, sign in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
            value = getattr(item, attr, None)
            if value is not None:  # annotated_types' Gt/Ge/Lt/Le carry one of these
                words.append(f"{sign} {value:g}" if isinstance(value, float) else f"{sign} {value}")
    return " and ".join(words) or None


_OUT_OF_RANGE = {"greater_than", "greater_than_equal", "less_than", "less_than_equal"}


def _dotted(loc: Sequence[int | str]) -> str:
    text = ""
    for part in loc:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return one_line(text, MAX_QUOTE_CHARS)


def validation_message(model: type[BaseModel], err: ValidationError, where: str) -> str:
    """The first error as `where: section.field = value: problem (allowed: range)`."""
    first = err.errors()[0]
    loc = first["loc"]
    problem = one_line(str(first["msg"]).removeprefix("Value error, "), MAX_MESSAGE_CHARS)
    # A whole-model check (a validator of the model itself) has no field to name.
    text = f"{one_line(where)}: {_dotted(loc)}" if loc else one_line(where)
    if "input" in first and not isinstance(first["input"], dict):
        text += f" = {short(first['input'])}"
    bounds = allowed_range(model, loc)
    if bounds is not None and first["type"] in _OUT_OF_RANGE:
        return f"{text}: must be {bounds}"
    text += f": {problem}"
    if bounds is not None:
        text += f" (allowed: {bounds})"
    return text
