"""Where the per-user caches live: the model cache and the training datasets.

The default is the user's cache directory (`platformdirs.user_cache_dir("sonarmap")`,
e.g. `~/.cache/sonarmap` on Linux), so every working directory of one user shares one
cache, as with any tool installed by pip. `SONARMAP_CACHE_DIR` moves it (tests, a
shared scratch disk); the config's `training.directory` moves the training data and
the model cache for one run. Directories are run options: no key depends on them.
"""

from __future__ import annotations

import os
from pathlib import Path

import platformdirs

from sonarmap.pipeline.engine.errors import ConfigError

__all__ = ["CACHE_ENV", "TRAINING_SUBDIR", "cache_root", "default_training_directory"]

CACHE_ENV = "SONARMAP_CACHE_DIR"
"""Environment variable naming the cache root (overrides the user's cache directory)."""

TRAINING_SUBDIR = "training"
"""Folder of the training datasets (and of the model cache `store/`) in the cache root."""


def cache_root() -> Path:
    """`$SONARMAP_CACHE_DIR` when set and not empty, else the user's cache directory."""
    override = os.environ.get(CACHE_ENV, "").strip()
    if override:
        # Absolute, so a later change of working directory cannot move the cache.
        root = Path(override).expanduser().absolute()
        if root.exists() and not root.is_dir():  # else named as a broken manifest under it
            raise ConfigError(f"{CACHE_ENV}={override}: a file, not a folder")
        return root
    return Path(platformdirs.user_cache_dir("sonarmap", appauthor=False))


def default_training_directory() -> Path:
    """The default `training.directory`: `<cache root>/training`."""
    return cache_root() / TRAINING_SUBDIR
