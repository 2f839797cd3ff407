"""Config section `keyframes` (imports no numpy or pyarrow: planning reads it)."""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import Field, SerializerFunctionWrapHandler, model_serializer

from sonarmap.stages.base import StageConfig

__all__ = ["KeyframesConfig"]

_MountM = Annotated[float, Field(ge=-100.0, le=100.0)]
_MountDeg = Annotated[float, Field(ge=-360.0, le=360.0)]


class KeyframesConfig(StageConfig):
    """Config section `keyframes`.

    Attributes:
        spacing_m: new keyframe after this much travel (3D) since the last one [m].
        rotation_deg: ... or after this much |yaw change| [deg].
        min_gap_s: never two keyframes closer in time than this [s].
        pair_tolerance_s: largest |t_h - t_v| of a sonar pair [s].
        horizontal_topic, vertical_topic: sonar topics (None: found by type/name).
        navigation_topic: Odometry/PoseStamped/PoseWithCovarianceStamped topic (None: found).
        ground_truth_topic: true pose topic (None: /ground_truth/odometry if present).
        dvl_topic, imu_topic: dead-reckoning inputs when no navigation topic.
        depth_topic: depth source (FluidPressure, a `depth` field, or a pose's z); with a
            navigation topic it replaces the navigation's z.
        dvl_max_velocity_mps: DVL samples faster than this are dropped as implausible [m/s]
            (a limit well above vehicle speed; the drops are counted and reported).
        water_density_kg_m3, gravity_m_s2: depth from pressure, (p - p_surface) / (rho g).
        surface_pressure_pa: p_surface [Pa] (None: from `surface_pressure_from_first_s`,
            else one standard atmosphere).
        surface_pressure_from_first_s: take p_surface as the median pressure of the
            recording's first seconds (the vehicle at the surface).
        image_fov_deg, image_max_range_m: beam table of polar sensor_msgs images (both
            sonars; evenly spaced beams) where a sonar has no preset or table of its own.
        horizontal_sonar, vertical_sonar: the sonar's geometry: a preset name
            (`configs/sonars/`, e.g. "oculus-m750d-750khz", "aris3000-128") or a CSV/YAML
            file of beam angles [deg] in image-column order, positive to the sonar's left.
            Gives polar images their (possibly uneven) beam table, and every sonar its
            fan, range and vertical aperture in `sensors.json` (None: from the messages).
        horizontal_image_max_range_m, vertical_image_max_range_m: range of that sonar's
            polar images [m] (None: image_max_range_m).
        image_bits: significant bits of a 16-bit sonar image's pixels (a sonar writing
            12-bit values in mono16 or a 16-bit PNG: 12); its top 8 bits are the echo
            intensity (None: all 16).
        message_definitions: `.msg` / `.idl` files of custom ROS 2 message types the
            recording uses (a .msg file's type is its path: pkg/msg/Name.msg).
        base_frame: the vehicle frame mounts are composed from in the recording's tf tree.
        *_mount_xyz_m, *_mount_rpy_deg: T_base_sensor; None takes it from the recording's
            /tf_static (/tf) tree by the sensor messages' frame_id, else a default (warned).
            Set, they override the recording.
        calibration_pairs: ping pairs the front end calibrates on (stage `features`): those
            nearest to a grid of absolute ping time (`sonarmap.stages.kernels.time_grid`),
            decoded beside the keyframes whatever the selection settings above.
        submap_stride: dense submaps (stage `submaps`): every keyframe also maps every
            k-th ping pair recorded between it and the next keyframe; 0 maps keyframes
            only (the paper). Read by `submaps` only, so it is not in this stage's key.
        files_sha256: filled by sonarmap, never by hand: the sha256 of each file the
            settings above name (a sonar's preset or beam table, message definitions), so
            that an edited file changes the keys as an edited setting does. Left out of
            the config (and its keys) when no setting names a file.
    """

    spacing_m: float = Field(2.0, gt=0.0, le=1000.0)
    rotation_deg: float = Field(30.0, gt=0.0, le=360.0)
    min_gap_s: float = Field(1.0, ge=0.0, le=3600.0)
    pair_tolerance_s: float = Field(0.1, ge=0.0, le=60.0)
    horizontal_topic: str | None = Field(None, min_length=1)
    vertical_topic: str | None = Field(None, min_length=1)
    navigation_topic: str | None = Field(None, min_length=1)
    ground_truth_topic: str | None = Field(None, min_length=1)
    dvl_topic: str | None = Field(None, min_length=1)
    imu_topic: str | None = Field(None, min_length=1)
    depth_topic: str | None = Field(None, min_length=1)
    dvl_max_velocity_mps: float = Field(5.0, gt=0.0, le=50.0)
    water_density_kg_m3: float = Field(1025.0, ge=900.0, le=1100.0)
    gravity_m_s2: float = Field(9.80665, ge=9.7, le=9.9)
    surface_pressure_pa: float | None = Field(None, ge=50_000.0, le=120_000.0)
    surface_pressure_from_first_s: float | None = Field(None, gt=0.0, le=3600.0)
    image_fov_deg: float = Field(130.0, gt=0.0, le=360.0)
    image_max_range_m: float = Field(30.0, gt=0.0, le=1000.0)
    horizontal_sonar: str | None = Field(None, min_length=1, max_length=4096)
    vertical_sonar: str | None = Field(None, min_length=1, max_length=4096)
    horizontal_image_max_range_m: float | None = Field(None, gt=0.0, le=1000.0)
    vertical_image_max_range_m: float | None = Field(None, gt=0.0, le=1000.0)
    image_bits: int | None = Field(None, ge=8, le=16)
    message_definitions: tuple[Annotated[str, Field(min_length=1, max_length=4096)], ...] = Field(
        (), max_length=64
    )
    base_frame: str = Field("base_link", min_length=1, max_length=200)
    horizontal_mount_xyz_m: tuple[_MountM, _MountM, _MountM] | None = None
    horizontal_mount_rpy_deg: tuple[_MountDeg, _MountDeg, _MountDeg] | None = None
    vertical_mount_xyz_m: tuple[_MountM, _MountM, _MountM] | None = None
    vertical_mount_rpy_deg: tuple[_MountDeg, _MountDeg, _MountDeg] | None = None
    dvl_mount_xyz_m: tuple[_MountM, _MountM, _MountM] | None = None
    dvl_mount_rpy_deg: tuple[_MountDeg, _MountDeg, _MountDeg] | None = None
    imu_mount_rpy_deg: tuple[_MountDeg, _MountDeg, _MountDeg] | None = None
    calibration_pairs: int = Field(24, ge=1, le=1000)
    submap_stride: int = Field(0, ge=0, le=10000)
    files_sha256: dict[str, str] = Field(default_factory=dict, max_length=80)

    @model_serializer(mode="wrap")
    def _without_empty_files(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        data = handler(self)
        if not data.get("files_sha256"):  # no file named: keys as before the field
            data.pop("files_sha256", None)
        return data
