"""The simulator's version, importable without loading open3d (dataset caches check it)."""

SIM_VERSION = "1.0.0"
"""Bumped whenever the same (scene, config, seed) would give different data."""
