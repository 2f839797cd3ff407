"""Features: SOCA-CFAR detections on both polar images of every keyframe (paper Sec. IV.C).

Each image is searched along range, per beam, by `stages.kernels.cfar.cfar_detect` (SOCA by
default; CA, GO and OS through config), ANDed with an intensity floor; every detected
cell is one feature row (schema `schemas.features.FEATURES_SCHEMA`).

Defaults (`FeaturesConfig`): SOCA with 10 training + 5 guard cells per side (the
authors' Ntc = 20, Ngc = 10), Pfa = 0.1 and an intensity floor of 20 levels, lower than
the authors' floors, which were set for denoised or Cartesian images and lose weak
returns in ours (docs/decisions/005-cfar-defaults.md).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import pyarrow as pa
from pydantic import Field

from schemas.features import FEATURES_SCHEMA, SONARS
from schemas.sonar import KeyframeImages
from stages.base import Input, Output, Stage, StageConfig
from stages.kernels.cfar import CfarMethod
from stages.kernels.frame_features import detect_ping, keyframe_features

__all__ = ["STAGE", "FeaturesConfig", "detect_ping", "features_table", "keyframe_features"]


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


def features_table(frames: Iterable[KeyframeImages], config: FeaturesConfig) -> pa.Table:
    """`features.parquet` for a sequence of keyframes (one keyframe in memory at a time).

    Raises:
        ValueError: keyframe ids not strictly increasing.
    """
    chunks: list[dict[str, np.ndarray]] = []
    last = -1
    for frame in frames:
        if frame.keyframe_id <= last:
            raise ValueError(f"features: keyframe ids must increase, got {frame.keyframe_id}")
        last = frame.keyframe_id
        chunks.append(keyframe_features(frame, config))
    names = [f.name for f in FEATURES_SCHEMA]
    if not chunks:
        return FEATURES_SCHEMA.empty_table()
    cols = {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}
    sonar = pa.DictionaryArray.from_arrays(
        pa.array(cols.pop("sonar_index").astype(np.int32)), pa.array(list(SONARS))
    ).cast(pa.string())
    arrays = [sonar if n == "sonar" else pa.array(cols[n]) for n in names]
    return pa.Table.from_arrays(arrays, schema=FEATURES_SCHEMA)


def run(config: FeaturesConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    """Stage entry point: {"keyframes.frames": Sequence[KeyframeImages]} -> {"features"}."""
    return {"features": features_table(inputs["keyframes.frames"], config)}


STAGE = Stage(
    name="features",
    version=1,
    config=FeaturesConfig,
    inputs=(Input("keyframes", "frames"),),
    outputs=(Output("features", "parquet", "features.parquet", schema=FEATURES_SCHEMA),),
    run=run,
    description="SOCA-CFAR detections on both polar images of every keyframe",
)
