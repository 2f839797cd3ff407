"""The grid of a sweep: each `--set key=v1,v2,...` as an axis of (key, value) points,
checked so that no point is run, or counted, twice."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from sonarmap.pipeline.engine.errors import ConfigError

__all__ = ["sweep_axes"]


def sweep_axes(
    datasets: Sequence[Path], sweep_sets: Sequence[str], base_overrides: Sequence[str] = ()
) -> list[list[tuple[str, str]]]:
    """One axis of (key, value) per `key=v1,v2,...` of `sweep_sets`.

    Raises:
        ConfigError: a list with no value, a value given twice in one list (2 and 2.0
            included: one deterministic run would count as two replicates with a spread
            of 0), a key swept by two `--set`s or also fixed by `--fix`, or a dataset
            given twice.
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
        axis = [(key, v.strip()) for v in values.split(",") if v.strip()]
        if not axis:
            raise ConfigError(f"--set '{text}': no value to sweep")
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
