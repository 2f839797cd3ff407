"""How a keyframes artifact names its recording: by a placeholder, never by its path."""

from __future__ import annotations

__all__ = ["RECORDING", "path_free", "with_path"]

RECORDING = "{recording}"
"""Stands for the recording's path at the start of each warning an artifact keeps. Keys
hold the recording's content, not where it lies, so one key must hold the same bytes
whatever the file is called and wherever it is (the runner puts the path back when it
prints them)."""


def path_free(line: str, path: str) -> str:
    """`line` with a leading `path` replaced by `RECORDING`."""
    return RECORDING + line[len(path) :] if path and line.startswith(path) else line


def with_path(line: str, path: str) -> str:
    """`line` with a leading `RECORDING` replaced by `path` (`path_free` undone)."""
    return path + line[len(RECORDING) :] if line.startswith(RECORDING) else line
