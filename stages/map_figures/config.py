"""Config section `map_figures` (imports no numpy or pyarrow: planning reads it)."""

from __future__ import annotations

from sonarmap.stages.base import StageConfig

__all__ = ["MapFiguresConfig"]


class MapFiguresConfig(StageConfig):
    """Config section `map_figures` (`errors.png`, `map_topdown.png`, `side_view.png`;
    the pilings of the side view are evaluate's `side_view_pilings`)."""
