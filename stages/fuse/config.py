"""Config section `fuse` (imports no numpy or pyarrow: planning reads it)."""

from __future__ import annotations

from pydantic import Field, model_validator

from sonarmap.stages.base import StageConfig
from sonarmap.stages.kernels.choices import ConfidenceRule

__all__ = ["FuseConfig"]


class FuseConfig(StageConfig):
    """Config section `fuse`.

    Attributes:
        patch_size_px: side of the square patch of Eq. 5 (odd) [pixels].
        horizontal_aperture_deg: vertical extent of the horizontal sonar's beams [deg].
        vertical_aperture_deg: horizontal extent of the vertical sonar's beams [deg].
        min_confidence: associations with confidence below this are culled (-1: none).
        rotate_vertical_patch: rotate the vertical patch 90 deg before comparing (paper).
        min_subproblem_features: smallest horizontal and vertical set of a solved range bin.
        confidence_rule: "paper" (Eq. 6) or "ratio" (the original code's; module docstring).
        max_cost_ratio: ratio rule only: keep associations with L_ij / L_2 below this.
    """

    patch_size_px: int = Field(5, ge=1, le=63)
    horizontal_aperture_deg: float = Field(20.0, gt=0.0, lt=180.0)
    vertical_aperture_deg: float = Field(20.0, gt=0.0, lt=180.0)
    min_confidence: float = Field(-1.0, ge=-1.0, le=1.0)
    rotate_vertical_patch: bool = True
    min_subproblem_features: int = Field(
        1,
        ge=1,
        le=100000,
        description="a range-bin subproblem is solved only if both its horizontal and its"
        " vertical set have at least this many features (1: every bin; original code: 3)",
    )
    confidence_rule: ConfidenceRule = Field(
        "paper",
        description="'paper': Eq. 6, (L_2 - L_ij) / sum L; 'ratio': rho = L_ij / L_2 of the"
        " bin's smaller-set feature, the original code's per-feature cost ratio, stored as"
        " confidence (1 - rho) / (1 + rho)",
    )
    max_cost_ratio: float | None = Field(
        None,
        gt=0.0,
        le=1.0,
        description="with confidence_rule 'ratio', keep associations whose cost ratio"
        " L_ij / L_2 is below this (None: keep all; original code 0.97 sim, 0.98 real)",
    )

    @model_validator(mode="after")
    def _ratio_cut_needs_ratio_rule(self) -> FuseConfig:
        if self.max_cost_ratio is not None and self.confidence_rule != "ratio":
            raise ValueError("max_cost_ratio needs confidence_rule 'ratio'")
        if self.patch_size_px % 2 == 0:  # a patch centred on its pixel (Eq. 5)
            raise ValueError(f"patch_size_px must be odd, got {self.patch_size_px}")
        return self
