"""Config section `figures` (imports no numpy or pyarrow: planning reads it)."""

from __future__ import annotations

from pydantic import Field

from sonarmap.stages.base import StageConfig

__all__ = ["FiguresConfig"]


class FiguresConfig(StageConfig):
    """Config section `figures` (`overlay.png` and `trajectory.png`)."""

    overlay: bool = Field(
        True,
        description="draw overlay.png of the keyframe with the most accepted objects"
        " (was classify.overlay)",
    )
