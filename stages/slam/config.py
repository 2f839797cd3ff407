"""Config of the `slam` stage (paper Sec. IV.A; defaults after the authors' `slam.yaml`,
`icp.yaml`, changed where the factor-level diagnostic against ground truth says so)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import Field, model_validator

from sonarmap.stages.base import StageConfig

if TYPE_CHECKING:
    from sonarmap.schemas.sensors import Sensors

__all__ = ["CHI2_99_3DOF", "SlamConfig"]

CHI2_99_3DOF = 11.344866730144373
"""chi2.ppf(0.99, 3) (a test checks it against scipy)."""
"""11.34: the 99 % chi-square quantile with 3 degrees of freedom (the authors' threshold)."""


_WindowM = Annotated[float, Field(gt=0, le=1000)]
_WindowDeg = Annotated[float, Field(gt=0, le=360)]


class SlamConfig(StageConfig):
    """Config of the `slam` stage.

    Defaults are the authors' (`slam.yaml`, `icp.yaml`) except the heading factor, the SSM
    covariance floor and its mode, and the loops' Cauchy kernel, which the per-factor error
    against simulator ground truth set (`benchmarks/bench_slam.py`); the navigation factors
    (odometry white noise, its scale error, the heading's noise and bias walk) are those of
    the simulator's default navigation (`sonarmap.sim.config.NavigationNoise`), i.e. of the vehicle's
    sensor specifications: set them from yours.
    """

    mode: Literal["slam", "dead_reckoning", "ground_truth"] = "slam"
    prior_sigma_xy_m: float = Field(0.1, ge=1e-6, le=10000)
    prior_sigma_yaw_deg: float = Field(0.573, ge=1e-6, le=360, description="0.01 rad")
    odom_sigma_xy_m_sqrt_s: float = Field(
        0.0075,
        ge=1e-6,
        le=100,
        description="white noise of the odometry's position per sqrt(s) of the step's"
        " duration (the scale error is a state, `odom_scale_sigma`): a DVL's 0.02 m/s at"
        " 10 Hz gives 0.0063 (the simulator's default navigation; measured 0.012-0.018 m"
        " over its 4 s keyframe steps); with odom_scale_sigma None it must also cover the"
        " scale error",
    )
    odom_sigma_yaw_deg: float = Field(
        0.42,
        ge=1e-6,
        le=360,
        description="per keyframe step: the difference of two AHRS headings, each with"
        " 0.3 deg white noise (measured 0.38-0.48)",
    )
    odom_scale_sigma: float | None = Field(
        0.01,
        ge=1e-6,
        le=10,
        description="prior std of the odometry's per-axis scale error (a DVL's: fixed over a"
        " mission; the simulator's default navigation), estimated as a state; None: no scale"
        " state. Loops come out short by 0.1-1 % of their baseline (ICP on leading edges), a"
        " bias they share that this state absorbs: set it from your DVL's specification",
    )
    odom_chain_sigma_xy_m: float = Field(
        0.05,
        ge=1e-6,
        le=1000,
        description="per-step std of the odometry chain that sizes loop search windows and"
        " gates (covers the scale error's drift too)",
    )
    heading_sigma_deg: float | None = Field(
        0.3,
        ge=1e-6,
        le=360,
        description="mode slam: absolute heading factor per keyframe from the navigation yaw"
        " (AHRS heading), its white noise; None: off",
    )
    heading_bias_walk_deg_sqrt_s: float | None = Field(
        0.02,
        gt=0,
        le=360,
        description="random walk of the heading's bias [deg/sqrt(s)] (the simulator's AHRS:"
        " 0.02): each heading factor measures yaw through a bias state chained by this walk,"
        " so loops correct the wandering part; None: independent heading priors",
    )
    heading_first_bias_sigma_deg: float = Field(
        5.0, ge=1e-6, le=360, description="prior std of the first bias state (a gauge: weak)"
    )
    ssm_replaces_odometry: bool = Field(
        False, description="authors: SSM replaces odometry; default: both factors are fused"
    )
    icp_sigma_xy_m: float = Field(
        0.03,
        ge=1e-6,
        le=1000,
        description="floor of an SSM covariance (measured SSM error 0.02-0.05 m)",
    )
    icp_sigma_yaw_deg: float = Field(
        0.2, ge=1e-6, le=360, description="measured SSM error 0.16-0.21 deg"
    )
    covariance_floor: Literal["replace", "scale"] = Field(
        "scale", description="scale keeps the ICP Hessian's x-yaw correlation (lever arm)"
    )
    degeneracy_min_ratio: float | None = Field(
        0.05,
        gt=0,
        lt=1,
        description="a scan match leaves a direction of translation unconstrained when its"
        " point-to-line information there (yaw marginalised) is under this fraction of that"
        " along the best direction (0.05: the normals' RMS component along it under about"
        " sin 13 deg; `sonarmap.stages.slam.degeneracy`): its factor is made free along it"
        " and the odometry carries that direction; None: off",
    )
    degeneracy_tilt_deg: float | None = Field(
        None,
        gt=0,
        lt=90,
        description="how far a wall's apparent direction may be off its true one (grazing"
        " beams tilt it): a degenerate factor's variance across its free direction grows"
        " by (motion along it, at most the matched structure's length, x tan of this)^2;"
        " 12.921 is the check's own angle at 0.05 (asin sqrt 0.05); docs/slam.md: it fixes"
        " fan_edge but costs the demo marina 0.079 -> 0.091 m; None: off",
    )
    ssm_gate_probability: float | None = Field(
        0.999,
        gt=0,
        lt=1,
        description="a sequential match must agree with the odometry of its step: the"
        " Mahalanobis distance of their difference under the sum of the match's and the"
        " odometry's covariance over the step (white noise for its duration plus the scale"
        " error's share of its length) within this chi-square quantile, with as many degrees"
        " of freedom as the match constrains; None: only ssm_max_translation_m/rotation",
    )
    ssm_huber_k: float | None = Field(
        1.345,
        gt=0,
        le=1000000,
        description="Huber kernel scale on sequential scan-matching factors (whitened error;"
        " 1.345: 95 % efficiency under Gaussian noise); None: Gaussian",
    )
    loop_sigma_xy_m: float = Field(
        0.1, ge=1e-6, le=1000, description="floor of a loop's covariance"
    )
    loop_sigma_yaw_deg: float = Field(0.573, ge=1e-6, le=360)
    point_resolution_m: float = Field(
        0.25,
        ge=0.001,
        le=100,
        description="voxel size of keyframe clouds: each keyframe's leading edges are"
        " thinned to one centroid per voxel before scan matching, which bounds its points"
        " by the area the sonar sees over the voxel area whatever the detections",
    )
    lone_cell_beams: int | None = Field(
        2,
        ge=0,
        le=1000,
        description="before thinning, a leading edge needs `lone_cell_min_neighbours` other"
        " detections within this many beams and `lone_cell_bins` range bins of it in its"
        " image, else it is a lone false alarm and dropped. Counted in cells because the"
        " front end's false-alarm rate is per cell: a metric radius holds many more cells"
        " near the sonar, where false alarms then pass it, than at a far piling"
        " (open_pilings, benchmarks/bench_slam_degeneracy.py); None: off",
    )
    lone_cell_bins: int = Field(6, ge=0, le=10000, description="range half-width of that window")
    lone_cell_min_neighbours: int = Field(
        3, ge=1, le=10000, description="detections (itself not counted) that window needs"
    )
    outlier_radius_m: float | None = Field(
        1.0,
        gt=0,
        le=100,
        description="after thinning, a keyframe point needs `outlier_min_neighbours` others"
        " within this radius, else it is dropped before scan matching (the authors' PCL"
        " RadiusOutlierRemoval: 1.0 m, 5). It also drops the sparse features that pin a"
        " canal's along-wall direction (benchmarks/bench_slam_degeneracy.py, canal seeds"
        " 0/1: ATE 0.044/0.057 -> 0.070/0.113 m, dead reckoning 0.122/0.183); it halves"
        " the error under a moderate flood (bench_noise_cost floor0: 0.27 -> 0.13 m);"
        " None: off",
    )
    outlier_min_neighbours: int = Field(
        5, ge=1, le=10000, description="neighbours (itself not counted) of the outlier filter"
    )
    max_points_per_keyframe: int | None = Field(
        2000,
        ge=10,
        le=10000000,
        description="after the outlier filter, a keyframe holding more points keeps"
        " this many, those with the most neighbours (a warning with counts): scan matching's cost"
        " per keyframe stays within a few clean ones' (the clean demo marina's busiest"
        " keyframe holds 636 points, so nothing is clipped there); None: no budget",
    )
    leading_edge_only: bool = Field(True, description="first cell of each run along a beam")
    # Bounded so that the dilated grid and the overlap queries stay bounded: at 30 m the
    # overlap neighbourhoods took 21 GB, at a 1 cm grid the consensus search minutes.
    point_noise_m: float = Field(0.5, gt=0, le=5, description="grid dilation and overlap radius")
    grid_resolution_m: float = Field(0.25, ge=0.05, le=100, description="consensus grid cell")
    max_correspondence_m: float = Field(1.0, gt=0, le=1000, description="ICP correspondence gate")
    search_max_points: int = Field(
        150, ge=10, le=1000000, description="source points scored in the search"
    )
    icp_effective_samples: float | None = Field(
        4.0, gt=0, le=1000000, description="independent residuals assumed in the ICP covariance"
    )
    search_tie_fraction: float = Field(
        0.9, gt=0, le=1, description="consensus within this of the best: nearest the guess wins"
    )
    icp_max_iterations: int = Field(40, ge=1, le=10000)
    min_points: int = Field(
        10,
        ge=3,
        le=1000000,
        description="points needed in source and target. Whether they pin the motion down is"
        " the degeneracy check's to say, not a count's: this only keeps ICP off near-empty"
        " keyframes. A lone piling 15-30 m out leaves about 10 points once thinned, two in"
        " view 20 (30 until version 13, which refused every match in open water)",
    )
    min_overlap_points: int = Field(
        10, ge=3, le=1000000, description="overlapping points to accept (as min_points)"
    )
    ssm_target_frames: int = Field(3, ge=1, le=1000)
    ssm_window_xy_m: float = Field(1.0, gt=0, le=1000, description="global search half-width")
    ssm_window_yaw_deg: float = Field(5.73, gt=0, le=360)
    ssm_max_translation_m: float = Field(
        2.0, gt=0, le=1000, description="max deviation from odometry"
    )
    ssm_max_rotation_deg: float = Field(30.0, gt=0, le=360)
    nssm_min_separation: int = Field(8, ge=1, le=100000, description="keyframes between loop ends")
    nssm_source_frames: int = Field(5, ge=1, le=1000)
    nssm_target_frames: int = Field(
        5, ge=1, le=1000, description="target frames around the best one"
    )
    nssm_max_candidates: int | None = Field(
        100,
        ge=1,
        le=1000000,
        description="older keyframes, the nearest to the new one, whose points are counted"
        " for a loop target: bounds the cost per keyframe on a mission that keeps revisiting"
        " one area (a 6-goal mission has fewer); None: all within reach",
    )
    nssm_min_frame_points: int = Field(10, ge=1, le=1000000)
    nssm_max_range_m: float = Field(30.0, gt=0, le=1000)
    nssm_max_heading_change_deg: float = Field(
        180.0,
        gt=0,
        le=360,
        description="loop targets seen with a heading within this of the current",
    )
    nssm_fallback_targets: int = Field(
        1,
        ge=0,
        le=1000,
        description="loop targets tried after the best one fails its checks (each from"
        " another stretch of the track)",
    )
    nssm_aperture_deg: float | None = Field(
        None,
        gt=0,
        le=360,
        description="horizontal fan of the loop-target visibility test [deg]; None: the"
        " horizontal sonar's fov_deg from the keyframes sensors (130 where they have none)",
    )
    nssm_window_xy_m: tuple[_WindowM, _WindowM] = (1.0, 5.0)
    nssm_window_yaw_deg: tuple[_WindowDeg, _WindowDeg] = (5.73, 20.0)
    nssm_max_translation_m: float = Field(10.0, gt=0, le=10000)
    nssm_max_rotation_deg: float = Field(60.0, gt=0, le=360)
    nssm_gate_chi2: float = Field(
        16.27,
        gt=0,
        le=1000000,
        description="chi2(0.999, 3) gate of a loop against the odometry chain",
    )
    loop_max_view_change_deg: float | None = Field(
        None,
        gt=0,
        le=180,
        description="a loop candidate whose matched structure is seen from directions more"
        " than this apart (median over its paired points) is rejected: a curved hull seen"
        " from another side returns from another part of its surface; None: off",
    )
    loop_cauchy_k: float | None = Field(
        1.0,
        gt=0,
        le=1000000,
        description="Cauchy kernel scale on loop factors (whitened error): loop errors are"
        " heavy-tailed (viewpoint-dependent sonar returns); None: Gaussian",
    )
    loop_refine_passes: int = Field(
        2,
        ge=0,
        le=100,
        description="after the incremental run: passes that re-register every accepted loop"
        " from the optimised poses (ICP only, no global search), each followed by a batch"
        " re-solve of the whole graph; 0: off",
    )
    loop_shared_window: int = Field(
        5,
        ge=0,
        le=100000,
        description="loops whose two ends are both within this many keyframes of another's"
        " share most of their sonar data, so their errors are correlated: in the loop"
        " re-registration each loop's covariance is multiplied by the number of accepted"
        " loops it shares with (itself included), so such a cluster counts about once; 0: off",
    )
    loop_baseline_growth_m: float | None = Field(
        4.0,
        gt=0,
        le=100000,
        description="in the loop re-registration each loop's covariance is multiplied by"
        " ((g + d) / (g + d_ref))^2, d its baseline: the loop error grows with the distance"
        " between its two keyframes (measured RMS about 0.02 + 0.005 d m, so g = 4 m is where"
        " it doubles from its zero-baseline value); None: off",
    )
    loop_reference_baseline_m: float = Field(
        18.0,
        gt=0,
        le=100000,
        description="baseline whose loop covariance the growth leaves unchanged",
    )
    ssm_refine_target_frames: int = Field(
        5,
        ge=0,
        le=1000,
        description="in each loop re-registration pass, also re-register every accepted SSM"
        " factor (ICP only, from the current poses) against this many previous keyframes;"
        " 0: off",
    )
    loop_refine_correspondence_m: float = Field(
        0.3, gt=0, le=1000, description="ICP correspondence gate of the loop re-registration"
    )
    pcm_queue_keyframes: int = Field(5, ge=0, le=100000)
    pcm_min_clique: int = Field(2, ge=1, le=10000)
    pcm_chi2_threshold: float = Field(CHI2_99_3DOF, gt=0, le=1000000, description="chi2(0.99, 3)")
    plot_max_points: int = Field(
        30000, ge=0, le=100000000, description="features kept in plot_points.parquet (drawn)"
    )

    @model_validator(mode="after")
    def _bounded_grid(self) -> SlamConfig:
        # The consensus grid is dilated by a disk of point_noise_m: its cost grows with the
        # square of their ratio (2 by default).
        if self.point_noise_m > 40 * self.grid_resolution_m:
            raise ValueError(
                f"point_noise_m ({self.point_noise_m:g}) must be at most 40 x"
                f" grid_resolution_m ({self.grid_resolution_m:g}): the grid's dilation disk"
            )
        return self


LEGACY_FAN_DEG = 130.0
"""The fan assumed for keyframes artifacts written before sensors.json carried `fov_deg`
(the paper's Oculus M750d)."""


def with_sensor_fan(config: SlamConfig, sensors: Sensors | Mapping[str, Any] | None) -> SlamConfig:
    """`config` with `nssm_aperture_deg` set: as configured, else the horizontal sonar's
    fan from the keyframes sensors, else `LEGACY_FAN_DEG`."""
    if config.nssm_aperture_deg is not None:
        return config
    from sonarmap.schemas.sensors import Sensors  # numpy: not while planning reads this module

    fan = None if sensors is None else Sensors.of(sensors).horizontal.fov_deg
    return config.model_copy(update={"nssm_aperture_deg": float(fan or LEGACY_FAN_DEG)})
