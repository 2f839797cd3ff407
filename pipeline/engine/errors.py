"""Typed errors. Known errors become a one-line message in the CLI (exit 2 or 1)."""

from __future__ import annotations

__all__ = [
    "ArtifactCorrupt",
    "ConfigError",
    "InternalError",
    "OutputError",
    "PipelineError",
    "SourceError",
    "StageFailed",
    "StoreError",
]


class PipelineError(Exception):
    """Base of every error sonarmap reports without a traceback."""

    exit_code = 2


class ConfigError(PipelineError):
    """A config file, section, key or value is invalid."""


class SourceError(PipelineError):
    """A dataset (file, topic, field) cannot be read or lacks what is needed."""


class StoreError(PipelineError):
    """The artifact store is missing, unreadable, or a path escapes it."""


class ArtifactCorrupt(StoreError):
    """An artifact's files do not match its manifest (size, sha256, paths)."""


class StageFailed(PipelineError):
    """A stage raised; nothing was committed. The message names the stage."""

    exit_code = 1


class InternalError(PipelineError):
    """A bug in sonarmap rather than a problem with the input."""

    exit_code = 1


class OutputError(PipelineError):
    """An output location the user named (the store, `--out`) cannot take the write:
    a full, read-only or over-quota filesystem. Bad input (exit 2), not a bug."""
