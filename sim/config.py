"""Simulator configuration (frozen pydantic): sonars and mountings, mission, navigation noise."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from sonarmap.stages.kernels.lazy import lazy

np = lazy("numpy")  # loads when a scene is built or drawn, not when a config is read

__all__ = ["MissionConfig", "Mounting", "NavigationNoise", "SimConfig", "SonarConfig"]

_DEFAULT_REFLECTIVITY: dict[str, float] = {
    "cylindrical_piling": 1.0,
    "rectangular_piling": 1.0,
    "seawall": 0.8,
    "boat_hull": 0.7,
    "truss": 0.9,
    "seafloor": 0.35,
}

_TEXTURE_KEYS = ("gain_db", "noise_corr_range", "noise_corr_beam", "noise_range_slope_db")
"""The image-character settings added for real sensors, neutral at 0 (the clean sensor)."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Mounting(_Model):
    """Sonar pose in base_link: translation [m] and fixed-axis roll/pitch/yaw [deg]."""

    translation_m: tuple[float, float, float] = (0.5, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def matrix(self) -> np.ndarray:
        """(4, 4) T_base_sonar."""
        from sonarmap.stages.kernels.geometry import matrix_from_rpy_product, se3

        return se3(matrix_from_rpy_product(np.deg2rad(self.rpy_deg)), self.translation_m)


class SonarConfig(_Model):
    """One Oculus-like wide-aperture imaging sonar and its image-formation model.

    Defaults: M750d-like, 130 deg fan, 20 deg aperture, 512 beams, 30 m at 5 cm bins.
    """

    fan_width_deg: float = Field(default=130.0, gt=0.0, lt=180.0)
    aperture_deg: float = Field(default=20.0, gt=0.0, lt=90.0)
    n_beams: int = Field(default=512, ge=2, le=2048)
    range_max_m: float = Field(default=30.0, gt=0.0)
    range_resolution_m: float = Field(default=0.05, gt=0.0)
    beam_width_deg: float = Field(
        default=1.0,
        gt=0.0,
        le=10.0,
        description="-3 dB beam width across the fan (M750d 1, M1200d 0.6)",
    )
    aperture_samples: int = Field(
        default=64,
        ge=1,
        le=512,
        description="rays per beam across the aperture; strata of aperture/K must be narrower"
        " than the thinnest target (64: a 0.2 m piling at 30 m)",
    )
    mounting: Mounting = Mounting()
    frequency_hz: float = 750e3
    sound_speed_m_s: float = 1500.0
    reflectivity: dict[str, float] = Field(default_factory=lambda: dict(_DEFAULT_REFLECTIVITY))
    incidence_exponent: float = Field(
        default=1.0, ge=0.0, description="cos(incidence)^n backscatter"
    )
    absorption_db_per_m: float = Field(default=0.05, ge=0.0, description="one-way loss after TVG")
    aperture_edge_gain: float = Field(
        default=0.5, gt=0.0, le=1.0, description="beam pattern at +-aperture/2"
    )
    saturation_intensity: float = Field(default=0.05, gt=0.0, description="intensity mapped to 255")
    display_gamma: float = Field(
        default=0.5, gt=0.0, le=1.0, description="8-bit level = 255 (I/I_sat)^gamma"
    )
    speckle: bool = True
    noise_mean_level: float = Field(
        default=4.0, ge=0.0, le=255.0, description="mean additive noise [levels]"
    )
    noise_shape: float = Field(
        default=2.0,
        ge=0.5,
        le=10.0,
        description="Weibull shape of the additive noise amplitude: 2 is Rayleigh; lower is"
        " spikier (higher speckle contrast), higher flatter (a bright, even background)",
    )
    gain_db: float = Field(
        default=0.0, ge=-40.0, le=40.0, description="gain on every return [dB of intensity]"
    )
    noise_corr_range: float = Field(
        default=0.0,
        ge=0.0,
        lt=1.0,
        description="lag-1 correlation along range of the Gaussian field behind the noise and"
        " the speckle (`sonarmap.sim.image_noise`); 0: white",
    )
    noise_corr_beam: float = Field(
        default=0.0, ge=0.0, lt=1.0, description="the same across beams; 0: white"
    )
    noise_range_slope_db: float = Field(
        default=0.0,
        ge=-40.0,
        le=40.0,
        description="background level change from the nearest to the farthest range bin [dB,"
        " 20 log10, linear in range]; noise_mean_level holds at mid range",
    )
    label_min_level: float = Field(
        default=10.0, ge=0.0, description="noise-free level for a labelled pixel"
    )
    max_splat_bins: int = Field(
        default=32,
        ge=1,
        description="max range gap (bins) between aperture neighbours that still share a surface",
    )

    @model_validator(mode="after")
    def _beam_width_covers_spacing(self) -> SonarConfig:
        spacing = self.fan_width_deg / self.n_beams
        if self.beam_width_deg < spacing:
            raise ValueError(
                f"beam_width_deg {self.beam_width_deg} is below the beam spacing {spacing:.3f} deg;"
                " targets could fall between beams"
            )
        return self

    def unrecorded(self) -> set[str]:
        """Image-character settings at their neutral value: left out of the config a
        recording carries, so the clean sensor's files keep their bytes (and hashes)."""
        return {k for k in _TEXTURE_KEYS if getattr(self, k) == 0.0}

    @property
    def textured(self) -> bool:
        """Gain, correlated noise or a range-dependent background asked for (else the
        clean sensor's white-noise path, whose bytes tests pin)."""
        return any(getattr(self, k) != 0.0 for k in _TEXTURE_KEYS)

    @property
    def n_ranges(self) -> int:
        """Number of range bins (range_max / resolution, rounded)."""
        return round(self.range_max_m / self.range_resolution_m)

    def ranges_m(self) -> np.ndarray:
        """(n_ranges,) float32 bin-centre ranges [m]: (k + 0.5) * resolution."""
        return ((np.arange(self.n_ranges) + 0.5) * self.range_resolution_m).astype(np.float32)

    def angles_rad(self) -> np.ndarray:
        """(n_beams,) float32 ascending beam-centre fan angles [rad], uniform over the fan."""
        half = np.deg2rad(self.fan_width_deg) / 2
        bw = 2 * half / self.n_beams
        return (-half + bw * (np.arange(self.n_beams) + 0.5)).astype(np.float32)


class MissionConfig(_Model):
    """The paper's protocol: random start, random free-water goals in nearest-neighbour order,
    A* paths on a 2D grid with clearance, constant speed and depth."""

    n_goals: int = Field(default=20, ge=1, le=1000)
    speed_m_s: float = Field(default=0.5, gt=0.0, le=5.0)
    depth_m: float = Field(default=2.0, ge=0.0)
    clearance_m: float = Field(default=2.0, ge=0.0)
    grid_resolution_m: float = Field(default=0.5, gt=0.0)
    heading_mode: Literal["path", "constant"] = "path"
    yaw_rate_deg_s: float = Field(
        default=20.0, gt=0.0, description="turn-in-place rate (heading_mode=path)"
    )
    duration_s: float | None = Field(
        default=None, gt=0.0, allow_inf_nan=False, description="cut the mission after this time"
    )
    min_goal_separation_m: float = Field(default=4.0, ge=0.0)


class NavigationNoise(_Model):
    """Dead-reckoning sensors: DVL body velocity, IMU yaw (biased), depth sensor."""

    rate_hz: float = Field(default=10.0, gt=0.0)
    dvl_noise_m_s: float = Field(
        default=0.02, ge=0.0, description="white noise per axis per sample"
    )
    dvl_scale_error: float = Field(
        default=0.01, ge=0.0, description="std of fixed per-axis scale error"
    )
    yaw_noise_deg: float = Field(default=0.3, ge=0.0)
    yaw_bias_deg: float = Field(default=1.0, ge=0.0, description="std of the initial yaw bias")
    yaw_bias_walk_deg_sqrt_s: float = Field(default=0.02, ge=0.0, description="bias random walk")
    depth_noise_m: float = Field(default=0.02, ge=0.0)


class SimConfig(_Model):
    """Everything `sonarmap.sim.dataset.simulate` needs besides the scene and the seed."""

    horizontal: SonarConfig = SonarConfig()
    vertical: SonarConfig = SonarConfig(
        frequency_hz=1.2e6,
        mounting=Mounting(translation_m=(0.5, 0.0, 0.1), rpy_deg=(90.0, 0.0, 0.0)),
    )
    mission: MissionConfig = MissionConfig()
    navigation: NavigationNoise = NavigationNoise()
    ping_rate_hz: float = Field(default=2.0, gt=0.0, le=50.0)
    start_time_ns: int = Field(default=1_700_000_000_000_000_000, ge=0)

    @model_validator(mode="after")
    def _check_vertical(self) -> SimConfig:
        for name in ("horizontal", "vertical"):
            unknown = set(getattr(self, name).reflectivity) - set(_DEFAULT_REFLECTIVITY)
            if unknown:
                raise ValueError(f"{name}.reflectivity has unknown classes {sorted(unknown)}")
        return self

    def unrecorded(self) -> dict[str, set[str]]:
        """`exclude` for this config's dump as a recording carries it (`SonarConfig.unrecorded`)."""
        return {s: self.sonar(s).unrecorded() for s in ("horizontal", "vertical")}

    def sonar(self, name: str) -> SonarConfig:
        """The horizontal or vertical sonar config."""
        if name not in ("horizontal", "vertical"):
            raise ValueError(f"unknown sonar {name!r}")
        return self.horizontal if name == "horizontal" else self.vertical
