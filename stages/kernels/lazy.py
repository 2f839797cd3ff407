"""Heavy libraries and stage code imported on first use.

Declaring the stages (the registry, config validation, `sonarmap status`, a fully cached
`sonarmap run`) should not pay seconds for numpy, pyarrow, torch, open3d, gtsam,
kiss-icp, scikit-learn and scipy's bigger submodules; the algorithms load them when they
first run. `lazy` is the pattern of scientific-python's `lazy_loader`, kept to a dozen
lines; `deferred` and `resolve` let a stage's declaration name its entry point and its
schemas as `module:attribute` (docs/decisions/020-cached-run-imports.md).
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import Any

__all__ = ["deferred", "lazy", "resolve"]


class _LazyModule:
    __slots__ = ("_module", "_name")

    def __init__(self, name: str) -> None:
        self._name = name
        self._module: ModuleType | None = None

    def __getattr__(self, attr: str) -> Any:
        if self._module is None:
            self._module = importlib.import_module(self._name)
        return getattr(self._module, attr)


def lazy(name: str) -> Any:
    """A stand-in for module `name` that imports it on first attribute access."""
    return _LazyModule(name)


def resolve(ref: Any) -> Any:
    """The object a `module:attribute` string names (imported now); anything else as is."""
    if not isinstance(ref, str):
        return ref
    module, sep, attr = ref.partition(":")
    if not sep or not module or not attr:
        raise ValueError(f"{ref!r}: not a 'module:attribute' reference")
    return getattr(importlib.import_module(module), attr)


class _Deferred:
    """A function named by `module:attribute`, imported on its first call. Picklable
    by its name (worker processes import the module themselves)."""

    __slots__ = ("ref",)

    def __init__(self, ref: str) -> None:
        self.ref = ref

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return resolve(self.ref)(*args, **kwargs)

    def __getstate__(self) -> str:
        return self.ref

    def __setstate__(self, state: str) -> None:
        self.ref = state

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _Deferred) and other.ref == self.ref

    def __hash__(self) -> int:
        return hash(self.ref)

    def __repr__(self) -> str:
        return f"deferred({self.ref!r})"


def deferred(ref: str) -> Any:
    """A callable standing for the function `ref` (`module:attribute`), imported when
    first called: a stage's `run` that planning never imports."""
    module, sep, attr = ref.partition(":")
    if not sep or not module or not attr:
        raise ValueError(f"{ref!r}: not a 'module:attribute' reference")
    return _Deferred(ref)
