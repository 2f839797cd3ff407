"""Config section `features` (imports no numpy or pyarrow: planning reads it)."""

from __future__ import annotations

from pydantic import Field

from sonarmap.stages.base import StageConfig
from sonarmap.stages.kernels.choices import CfarMethod

__all__ = ["FeaturesConfig"]


class FeaturesConfig(StageConfig):
    """Config section `features`.

    Attributes:
        method: CFAR variant: "soca" (paper), "ca", "go" or "os".
        train_cells_per_side: training cells on each side of the cell under test, along range.
        guard_cells_per_side: guard cells on each side, along range.
        pfa: desired false-alarm probability (sets the threshold factor, exponential model).
        os_rank: OS only, 1-based rank of the order statistic (0: train_cells_per_side).
        intensity_floor: a detection also needs an image level above this [0-255 levels].
    """

    method: CfarMethod = "soca"
    train_cells_per_side: int = Field(10, ge=1, le=200)
    guard_cells_per_side: int = Field(5, ge=0, le=200)
    pfa: float = Field(0.1, gt=0.0, lt=1.0)
    os_rank: int = Field(0, ge=0, le=400)
    intensity_floor: float = Field(20.0, ge=0.0, le=65535.0)
