"""Config section `features` (imports no numpy or pyarrow: planning reads it)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import (
    Field,
    SerializationInfo,
    SerializerFunctionWrapHandler,
    model_serializer,
    model_validator,
)

from sonarmap.stages.base import USER_SETTINGS, ConfigModel, StageConfig
from sonarmap.stages.kernels.choices import CfarMethod

__all__ = ["FeaturesConfig", "PinnedBands"]

Filter = Literal["box3x3", "box3x5", "box5x3", "box5x5", "beam3", "range3", "none"]

LowerQuantile = Annotated[float, Field(gt=0.0, lt=0.9)]
UpperQuantile = Annotated[float, Field(ge=0.9, lt=1.0)]


class PinnedBands(ConfigModel):
    """One sonar's thresholds taken whole from an earlier calibration (`calibration.json`
    of a features artifact, `features.calibration_from`), or written by hand: its range
    bands' edges [m] and each band's CFAR factor and intensity floor [levels], and the
    filter it detected on."""

    band_edges_m: tuple[Annotated[float, Field(ge=0.0, le=1e5)], ...] = Field(
        min_length=2, max_length=65
    )
    threshold_factor: tuple[Annotated[float, Field(gt=0.0, le=1e3)], ...] = Field(
        min_length=1, max_length=64
    )
    intensity_floor_levels: tuple[Annotated[float, Field(ge=0.0, le=65535.0)], ...] = Field(
        min_length=1, max_length=64
    )
    denoise: Filter = "none"

    @model_validator(mode="after")
    def _bands(self) -> PinnedBands:
        n = len(self.band_edges_m) - 1
        if any(b <= a for a, b in zip(self.band_edges_m, self.band_edges_m[1:], strict=False)):
            raise ValueError("band_edges_m must increase")
        if len(self.threshold_factor) != n or len(self.intensity_floor_levels) != n:
            raise ValueError(
                f"{n} bands (band_edges_m) need {n} threshold_factor and intensity_floor_levels"
                f" values, got {len(self.threshold_factor)} and {len(self.intensity_floor_levels)}"
            )
        return self


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

    calibration_from: str | None = Field(
        None,
        max_length=4096,
        description="a calibration.json of an earlier run: its thresholds are pinned"
        " (pinned_bands, read when the config loads); the file's path is not in the key,"
        " its thresholds are",
    )
    pinned_bands: dict[Literal["horizontal", "vertical"], PinnedBands] | None = Field(
        None,
        description="every band's threshold, per sonar, pinned (null: measured); the range"
        " bands must be the recording's (features.range_bands over its range window)",
    )

    @model_serializer(mode="wrap")
    def _keyed(
        self, handler: SerializerFunctionWrapHandler, info: SerializationInfo
    ) -> dict[str, Any]:
        data = handler(self)
        if not (info.context or {}).get(USER_SETTINGS):  # keys: its content is, as pinned_bands
            data.pop("calibration_from", None)
        if data.get("pinned_bands") is None:  # unpinned: keys as before the field
            data.pop("pinned_bands", None)
        return data

    def _check_pins(self, pinned: dict[str, PinnedBands]) -> None:
        """A whole calibration pinned leaves no threshold to set beside it: a setting that
        would be ignored is refused (it was recorded as pinned, yet not applied)."""
        if set(pinned) != {"horizontal", "vertical"}:
            raise ValueError("pinned_bands: pin both sonars (horizontal and vertical)")
        beside = {
            "intensity_floor": self.intensity_floor,
            "threshold_factor": self.threshold_factor,
        }
        beside["denoise"] = None if self.denoise == "auto" else self.denoise
        for name, value in beside.items():
            if value is not None:
                raise ValueError(
                    f"{name} ({value}) cannot be set beside pinned_bands (calibration_from),"
                    " which pins every band's floor, factor and filter"
                )
        for sonar, bands in sorted(pinned.items()):
            if len(bands.band_edges_m) - 1 != self.range_bands:
                raise ValueError(
                    f"pinned_bands: {sonar} sonar has {len(bands.band_edges_m) - 1} range bands,"
                    f" range_bands is {self.range_bands}"
                )

    @model_validator(mode="after")
    def _quantiles(self) -> FeaturesConfig:
        lo, hi = self.fit_quantiles
        if not 0.0 < lo < hi < 1.0:
            raise ValueError(f"fit_quantiles must satisfy 0 < lo < hi < 1, got {lo}, {hi}")
        if isinstance(self.threshold_factor, float) and not 0.0 < self.threshold_factor <= 1e3:
            raise ValueError("threshold_factor must be in (0, 1000]")
        if self.pinned_bands is not None:
            self._check_pins(self.pinned_bands)
        if self.method == "os" and self.os_rank > 2 * self.train_cells_per_side:
            raise ValueError(
                f"os_rank ({self.os_rank}) must be at most the training cells it ranks,"
                f" 2 x train_cells_per_side = {2 * self.train_cells_per_side}"
            )
        return self
