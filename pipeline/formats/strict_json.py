"""Strict JSON for everything sonarmap prints or writes as JSON.

Python's `json` writes bare `NaN` / `Infinity` by default, which strict parsers (jq,
JavaScript, most languages' standard libraries) refuse. Non-finite numbers become
`null`; numpy scalars and arrays become plain numbers and lists; anything else that is
not JSON becomes its string form.
"""

from __future__ import annotations

import json
import math
from typing import Any

__all__ = ["dumps_strict", "to_json_safe"]


def to_json_safe(value: Any) -> Any:
    """`value` with every non-finite float replaced by None, recursively."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: to_json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_json_safe(v) for v in value]
    return value


def _default(value: Any) -> Any:
    """Non-JSON values: numpy scalars and arrays as Python numbers/lists, else `str`."""
    tolist = getattr(value, "tolist", None)
    if callable(tolist) and type(value).__module__ == "numpy":
        return to_json_safe(tolist())
    return str(value)


def dumps_strict(doc: Any, *, indent: int | None = 2, sort_keys: bool = True) -> str:
    """`doc` as strict JSON (RFC 8259): no NaN or Infinity; keys sorted by default."""
    return json.dumps(
        to_json_safe(doc), indent=indent, sort_keys=sort_keys, default=_default, allow_nan=False
    )
