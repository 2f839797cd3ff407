"""Config section `features` (imports no numpy or pyarrow: planning reads it)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from sonarmap.stages.base import StageConfig
from sonarmap.stages.kernels.choices import CfarMethod

__all__ = ["FeaturesConfig"]

LowerQuantile = Annotated[float, Field(gt=0.0, lt=0.9)]
UpperQuantile = Annotated[float, Field(ge=0.9, lt=1.0)]


class FeaturesConfig(StageConfig):
    """Config section `features`: the detection front end.

    Every threshold is measured from the recording unless pinned here
    (`sonarmap.stages.features.calibration`): `null` = measured, a value = pinned, and a
    pinned value is reported as pinned in `calibration.json`. The fixed front end of
    before the calibration is `intensity_floor: 20, threshold_factor: exponential,
    denoise: none`.
    """

    method: CfarMethod = Field("soca", description='local CFAR: "soca" (paper), "ca", "go", "os"')
    train_cells_per_side: int = Field(
        10, ge=1, le=200, description="training cells on each side of the cell under test"
    )
    guard_cells_per_side: int = Field(5, ge=0, le=200, description="guard cells on each side")
    pfa: float = Field(
        0.1,
        gt=0.0,
        lt=1.0,
        description="false-alarm probability of the local CFAR test alone (the paper's 0.1):"
        " sets its threshold factor under the measured clutter law",
    )
    os_rank: int = Field(0, ge=0, le=400, description="OS only: 1-based rank (0: train cells)")
    false_alarm_rate_per_cell: float = Field(
        1e-3,
        gt=0.0,
        lt=0.5,
        description="stated per-cell false-alarm rate on background: sets each range band's"
        " intensity floor under its fitted clutter law",
    )
    intensity_floor: float | None = Field(
        None,
        ge=0.0,
        le=65535.0,
        description="null: measured per range band (false_alarm_rate_per_cell); a number:"
        " pinned for every band [image levels]",
    )
    threshold_factor: float | Literal["exponential"] | None = Field(
        None,
        description="local CFAR factor tau. null: measured per band (pfa under the fitted"
        " law); a number: pinned; 'exponential': the exponential-noise formula for pfa",
    )
    range_bands: int = Field(
        8, ge=1, le=64, description="range bands the background is fitted in (equal bin counts)"
    )
    fit_quantiles: tuple[LowerQuantile, UpperQuantile] = Field(
        (0.6, 0.95),
        description="the clutter law is fitted to this quantile range of each band: objects"
        " may fill up to 1 - upper of a band without moving the fit",
    )
    denoise: Literal["auto", "box3x3", "box3x5", "box5x3", "box5x5", "beam3", "range3", "none"] = (
        Field(
            "auto",
            description="filter before calibration and detection: auto = a 3x3 (range x beam)"
            " mean only for a sonar whose unfiltered background puts the stated rate's floor at"
            " full scale in most bands, else none (by measurement, docs/front-end.md)",
        )
    )
    max_features_per_keyframe_per_sonar: int | None = Field(
        20000,
        ge=1,
        le=10_000_000,
        description="feature budget per image: over it, the strongest (intensity, then"
        " nearest range, then beam) are kept, and the clipping is warned; null: no budget",
    )

    @model_validator(mode="after")
    def _quantiles(self) -> FeaturesConfig:
        lo, hi = self.fit_quantiles
        if not 0.0 < lo < hi < 1.0:
            raise ValueError(f"fit_quantiles must satisfy 0 < lo < hi < 1, got {lo}, {hi}")
        if isinstance(self.threshold_factor, float) and not 0.0 < self.threshold_factor <= 1e3:
            raise ValueError("threshold_factor must be in (0, 1000]")
        if self.method == "os" and self.os_rank > 2 * self.train_cells_per_side:
            raise ValueError(
                f"os_rank ({self.os_rank}) must be at most the training cells it ranks,"
                f" 2 x train_cells_per_side = {2 * self.train_cells_per_side}"
            )
        return self
