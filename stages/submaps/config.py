"""Config section `submaps` (stage `sonarmap.stages.submaps.stage`). The stride itself is
`keyframes.submap_stride`, beside the keyframe spacing it refines."""

from __future__ import annotations

from pydantic import Field

from sonarmap.stages.base import StageConfig

__all__ = ["READ_SECTIONS", "SubmapsConfig"]

READ_SECTIONS = ("keyframes", "features", "fuse", "infer")
"""Config sections, besides `classes`, that the stage reads and hashes into its key."""


class SubmapsConfig(StageConfig):
    """Config section `submaps`."""

    match_radius_m: float | None = Field(
        None,
        gt=0.0,
        le=100.0,
        description="a submap-frame return lies on a keyframe object within this of one of"
        " its returns (sonarmap.stages.submaps.transfer); None: the classifier's DBSCAN radius",
    )
    next_keyframe_objects: bool = Field(
        True, description="also match the objects of the next keyframe"
    )
    workers: int | None = Field(
        1,
        ge=1,
        le=256,
        description="processes mapping chunks of 64 frames (sonarmap.stages.kernels.parallel); None: one per"
        " available core. Not in the stage's key: the outputs are the same bytes for any"
        " number. 1 by measurement: on 2 cores, 2 workers map the default marina 0-25 %"
        " faster and hold about 0.8 GB more at once (benchmarks/bench_submaps.py)",
    )
