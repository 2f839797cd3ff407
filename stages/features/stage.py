"""Features: SOCA-CFAR detections on both polar images of every keyframe (paper Sec. IV.C).

Each image is searched along range, per beam, by `sonarmap.stages.kernels.cfar.cfar_detect` (SOCA by
default; CA, GO and OS through config), ANDed with an intensity floor; every detected
cell is one feature row (schema `sonarmap.schemas.features.FEATURES_SCHEMA`).

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

from sonarmap.schemas.features import FEATURES_SCHEMA, SONARS
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.features import STAGE
from sonarmap.stages.features.config import FeaturesConfig
from sonarmap.stages.kernels.frame_features import detect_ping, keyframe_features

__all__ = ["STAGE", "FeaturesConfig", "detect_ping", "features_table", "keyframe_features"]


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
