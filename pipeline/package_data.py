"""Where the files sonarmap ships live: `configs/` in a checkout, `sonarmap/configs/` in
an installed wheel. Found through `importlib.resources`, never through `__file__`, so an
installed package finds its scenes, sonar presets, default model and layout wherever it
is installed from."""

from __future__ import annotations

from functools import cache
from importlib.resources import files
from pathlib import Path

__all__ = ["configs_dir", "package_root"]


@cache
def configs_dir() -> Path:
    """The shipped `configs` folder (a real directory: sonarmap is never run from a zip)."""
    found = files("sonarmap.configs")
    path = Path(str(found))
    if not (path / "scenes").is_dir():
        raise RuntimeError(f"sonarmap's package data is missing: no scenes under {path}")
    return path


def package_root() -> Path:
    """The folder that holds `configs/`: the checkout, or the installed `sonarmap` package.
    Relative settings that name shipped files (`training.shipped_models: configs/model`)
    resolve against it."""
    return configs_dir().parent
