"""Heavy libraries imported on first use.

Declaring the stages (the registry, config validation, `sonarmap status`, a fully cached
`sonarmap run`) should not pay seconds for torch, open3d, gtsam, kiss-icp, scikit-learn
and scipy's bigger submodules; the algorithms load them when they first run. This is the
pattern of scientific-python's `lazy_loader`, kept to a dozen lines.
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import Any

__all__ = ["lazy"]


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
