"""The grid of a sweep: each `--set key=v1,v2,...` as an axis of (key, value) points,
checked so that no point is run, or counted, twice."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from sonarmap.pipeline.engine.errors import ConfigError

__all__ = ["sweep_axes"]


def sweep_axes(
    datasets: Sequence[Path],
    sweep_sets: Sequence[str],
    base_overrides: Sequence[str] = (),
    is_list_key: Callable[[str], bool] = lambda key: False,
) -> list[list[tuple[str, str]]]:
    """One axis of (key, value) per `key=v1,v2,...` of `sweep_sets`; a point of a list
    setting (`is_list_key`) is written in brackets, `key=[1,5],[2,6]`.

    Raises:
        ConfigError: a list with no value, a value given twice in one list (2 and 2.0
            included: one deterministic run would count as two replicates with a spread
            of 0), a key swept by two `--set`s or also fixed by `--fix`, a list setting
            whose points are not in brackets, or a dataset given twice.
    """
    axes: list[list[tuple[str, str]]] = []
    swept: dict[str, str] = {}
    for text in sweep_sets:
        key, sep, values = text.partition("=")
        key = key.strip()
        if not sep or not values:
            raise ConfigError(f"--set '{text}': expected section.field=v1,v2,...")
        if key in swept:
            raise ConfigError(
                f"--set '{text}': {key} is already swept by --set '{swept[key]}'; give one list"
            )
        swept[key] = text
        axis = [(key, v.strip()) for v in _points(values, text) if v.strip()]
        if not axis:
            raise ConfigError(f"--set '{text}': no value to sweep")
        if is_list_key(key) and not all(v.startswith("[") for _, v in axis):
            # Split at its commas, `key=1,5` would run a point of [1] and one of [5].
            raise ConfigError(
                f"--set '{text}': {key} is a list, so its commas cannot separate points;"
                f" write each point in brackets: --set '{key}=[1,5],[2,6]'"
                f" (or fix one list with --fix '{key}=1,5')"
            )
        seen: dict[object, str] = {}
        for _, value in axis:
            same = _value_identity(value)
            if same in seen:
                raise ConfigError(
                    f"--set '{text}': value {value} given twice (also as {seen[same]}):"
                    " each value is one point"
                )
            seen[same] = value
        axes.append(axis)
    for text in base_overrides:
        key = text.partition("=")[0].strip()
        if key in swept:
            raise ConfigError(f"--fix '{text}': {key} is also swept by --set '{swept[key]}'")
    resolved: dict[Path, Path] = {}
    for d in datasets:
        path = Path(d).resolve()
        if path in resolved:
            raise ConfigError(f"{d}: given twice (also as {resolved[path]}): each dataset once")
        resolved[path] = Path(d)
    return axes


def _value_identity(text: str) -> object:
    """What makes two swept values the same point: their number, when both are numbers
    (2 and 2.0), else their text."""
    try:
        return float(text)
    except ValueError:
        return text


def _points(values: str, text: str) -> list[str]:
    """`values` split at the commas outside brackets: `[1,5],[2,6]` is two points."""
    points, depth, start = [], 0, 0
    for i, ch in enumerate(values):
        depth += {"[": 1, "]": -1}.get(ch, 0)
        if depth < 0:
            raise ConfigError(f"--set '{text}': a ']' with no '[' before it")
        if ch == "," and depth == 0:
            points.append(values[start:i])
            start = i + 1
    if depth:
        raise ConfigError(f"--set '{text}': a '[' that is not closed")
    return [*points, values[start:]]
