"""The procedural generator's ranges (`sonarmap.sim.procedural`): a config section's type, so it
loads with the config, without the scene models or numpy."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = ["ProceduralConfig"]

Span = tuple[float, float]
Count = tuple[int, int]


class ProceduralConfig(BaseModel):
    """Ranges of the generator: every value is drawn uniformly from (low, high)."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    area_half_side_m: Span = (18.0, 30.0)
    depth_m: Span = (4.0, 15.0)
    walls: Count = (1, 3)
    wall_segments: Count = (1, 4)
    wall_segment_m: Span = (8.0, 30.0)
    wall_turn_deg: Span = (-110.0, 110.0)
    wall_curve_share: float = Field(0.35, ge=0.0, le=1.0)
    corrugation_period_m: Span = (0.6, 1.6)
    corrugation_depth_m: Span = (0.0, 0.35)
    piling_rows: Count = (1, 4)
    row_pilings: Count = (3, 10)
    row_spacing_m: Span = (2.0, 5.0)
    piling_grids: Count = (0, 2)
    grid_side: Count = (2, 4)
    grid_spacing_m: Span = (2.5, 6.0)
    dolphins: Count = (1, 4)
    dolphin_pilings: Count = (1, 3)
    round_radius_m: Span = (0.1, 0.6)
    square_side_m: Span = (0.3, 1.2)
    rectangular_aspect: Span = (1.0, 2.0)
    rectangular_share: float = Field(0.4, ge=0.0, le=1.0)
    truss_along_row_share: float = Field(0.5, ge=0.0, le=1.0)
    trusses_between_rows: Count = (0, 2)
    truss_top_z_m: Span = (-1.0, -0.2)
    truss_height_m: Span = (0.6, 1.6)
    hulls: Count = (1, 3)
    hull_length_m: Span = (4.0, 20.0)
    hull_beam_share: Span = (0.25, 0.4)
    hull_draft_m: Span = (0.6, 2.2)
    moored_share: float = Field(0.5, ge=0.0, le=1.0)
    open_water: bool = Field(
        True,
        description="remove the structures that close off free water from the default"
        " mission (`sonarmap.sim.open_water`), so it reaches every goal; false: the raw draw",
    )

    @model_validator(mode="after")
    def _ordered(self) -> ProceduralConfig:
        for name, value in self:
            if isinstance(value, tuple) and value[0] > value[1]:
                raise ValueError(f"{name}: low {value[0]} above high {value[1]}")
        return self
