"""Fuse: orthogonal stereo association of horizontal and vertical features (paper Sec. IV.B).

Per keyframe, `sonarmap.stages.kernels.fusion.fuse_keyframe` (shared with stage `submaps`):
overlap, subproblems per range bin with the cost of Eq. 5 and the confidence of Eq. 6,
and the Eq. 3 point. This module builds the `fused.parquet` table (config section:
`sonarmap.stages.fuse.config`; declaration: `sonarmap.stages.fuse`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from sonarmap.schemas.fused import FUSED_SCHEMA
from sonarmap.schemas.sensors import Sensors
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.fuse import STAGE
from sonarmap.stages.fuse.config import FuseConfig
from sonarmap.stages.kernels.fusion import fuse_keyframe, sonar_offset

__all__ = ["STAGE", "FuseConfig", "fuse_table"]


_FEATURE_COLUMNS = (
    "keyframe_id",
    "feature_id",
    "sonar",
    "range_bin",
    "beam",
    "range_m",
    "angle_rad",
)


def _feature_arrays(features: pa.Table) -> dict[str, np.ndarray]:
    """Feature columns as numpy, sorted by (keyframe_id, feature_id), `sonar` as a bool
    `is_horizontal`."""
    missing = [c for c in _FEATURE_COLUMNS if c not in features.column_names]
    if missing:
        raise ValueError(f"fuse: features table lacks columns {missing}")
    cols = {c: features.column(c).to_numpy() for c in _FEATURE_COLUMNS if c != "sonar"}
    is_h = pc.equal(features.column("sonar"), "horizontal")
    cols["is_horizontal"] = is_h.to_numpy(zero_copy_only=False).astype(bool)
    kf, fid = cols["keyframe_id"], cols["feature_id"]
    ordered = len(kf) < 2 or bool(
        np.all((kf[1:] > kf[:-1]) | ((kf[1:] == kf[:-1]) & (fid[1:] > fid[:-1])))
    )
    if ordered:
        return cols
    order = np.lexsort((fid, kf))
    return {c: v[order] for c, v in cols.items()}


def fuse_table(
    frames: Sequence[KeyframeImages],
    features: pa.Table,
    sensors: Sensors | Mapping[str, Any],
    config: FuseConfig,
) -> pa.Table:
    """`fused.parquet` for all keyframes (one keyframe's images in memory at a time)."""
    T_h_v = sonar_offset(sensors)
    cols = _feature_arrays(features)
    kf = cols["keyframe_id"]
    chunks: list[dict[str, np.ndarray]] = []
    for frame in frames:
        lo, hi = np.searchsorted(kf, [frame.keyframe_id, frame.keyframe_id + 1])
        if hi == lo:
            continue
        part = fuse_keyframe(frame, {c: v[lo:hi] for c, v in cols.items()}, T_h_v, config)
        part["keyframe_id"] = np.full(len(part["range_m"]), frame.keyframe_id, np.int64)
        chunks.append(part)
    if not chunks:
        return FUSED_SCHEMA.empty_table()
    arrays = [pa.array(np.concatenate([c[f.name] for c in chunks])) for f in FUSED_SCHEMA]
    return pa.Table.from_arrays(arrays, schema=FUSED_SCHEMA)


def run(config: FuseConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    """Stage entry point: keyframes.frames, keyframes.sensors, features.features -> fused."""
    table = fuse_table(
        inputs["keyframes.frames"], inputs["features.features"], inputs["keyframes.sensors"], config
    )
    return {"fused": table}
