"""The `keyframes` stage: pair the sonars in time, pose each pair, keep pairs by spacing.

This module declares the stage (what planning imports: no numpy, no pyarrow).

Modules:
    config: its config section.
    recording_facts: steps 1-2 of the whole recording, a work unit per dataset.
    stage: the computation (`sonarmap.stages.kernels.pairing` pairs and poses the pings).
"""

from sonarmap.stages.base import DATASET, Output, Stage
from sonarmap.stages.kernels.lazy import deferred
from sonarmap.stages.keyframes.config import KeyframesConfig

__all__ = ["STAGE", "KeyframesConfig"]

STAGE = Stage(
    name="keyframes",
    # 3: keyframes.mcap in LZ4 chunks (was zstd): same images, other bytes
    # 4: calibration.mcap, the ping pairs the front end calibrates on (issue 53); what
    # it reads of the whole recording is a work unit per dataset
    # 5: the reader warns of navigation samples sharing a time at two poses (sensors.json)
    # and refuses positions beyond any Earth-fixed frame
    # 6: the reader drops the fewer of two readings of a topic out of time order (a
    # sample stamped an hour late goes alone), counts the pings inside a jump of the
    # navigation's clock, warns of a sonar logged apart from its header stamps, and
    # refuses log times past what a ROS 2 stamp holds (sensors.json's warnings)
    # 7: sonar images: grey colour images read (false colour, unknown encodings, floats
    # outside 0..1 refused), `image_bits`, beam tables in no order or spanning no fan
    # refused, a compressed image's labels ordered by its decoded width; a depth sensor's
    # pose beside a DVL and an IMU is the depth, not the navigation; navigation warnings
    # (a vehicle on its side, depth above the surface, unposed pings); NED / FRD frames
    # by their REP 105 names converted to ENU / FLU
    # 8: sensors.json names no file: the recording's name left out of `source`, and its
    # warnings begin with "{recording}" where they named the path (same key, same bytes);
    # keyframes.mcap's pings carry the recording's ping_info (frequency, sound speed)
    version=8,
    config=KeyframesConfig,
    inputs=(DATASET,),
    outputs=(
        Output(
            "keyframes",
            "parquet",
            "keyframes.parquet",
            schema="sonarmap.schemas.keyframes:KEYFRAMES_SCHEMA",
        ),
        Output("frames", "frames", "keyframes.mcap"),
        Output("calibration_frames", "frames", "calibration.mcap"),
        Output("sensors", "json", "sensors.json", record="sonarmap.schemas.sensors:Sensors"),
        Output("scene_mesh", "bytes", "scene.ply", optional=True),
    ),
    run=deferred("sonarmap.stages.keyframes.stage:run"),
    units=True,
    description="pair sonar pings, pose them from navigation, select keyframes by spacing",
    key_excludes=("submap_stride",),
)
