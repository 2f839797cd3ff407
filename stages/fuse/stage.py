"""Fuse: orthogonal stereo association of horizontal and vertical features (paper Sec. IV.B).

Per keyframe, `sonarmap.stages.kernels.fusion.fuse_keyframe` (shared with stage `submaps`):
overlap, subproblems per range bin with the cost of Eq. 5 and the confidence of Eq. 6,
and the Eq. 3 point. This module builds the `fused.parquet` table (config section:
`sonarmap.stages.fuse.config`; declaration: `sonarmap.stages.fuse`).

Each keyframe's points are a work unit (`sonarmap.stages.base.Units`), keyed by the
stage's version and config, the sonars' relative mounting, the keyframe's images and axes
and its feature rows (not its id: the points hold none but the keyframe_id added here).
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
from sonarmap.stages.base import UNITS_INPUT, Units
from sonarmap.stages.fuse import STAGE
from sonarmap.stages.fuse.config import FuseConfig
from sonarmap.stages.kernels.fusion import fuse_keyframe, sonar_offset
from sonarmap.stages.kernels.unit_keys import array_digest, unit_key

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
    units: Units | None = None,
) -> pa.Table:
    """`fused.parquet` for all keyframes (one keyframe's images in memory at a time; each
    keyframe's points taken from `units`, the engine's memo, when it holds them)."""
    T_h_v = sonar_offset(sensors)
    cols = _feature_arrays(features)
    kf = cols["keyframe_id"]
    base = {
        "stage": STAGE.name,
        "version": STAGE.version,
        "config": config.model_dump(mode="json"),
        "T_h_v": array_digest(np.asarray(T_h_v, np.float64)),
    }
    chunks: list[dict[str, np.ndarray]] = []
    for frame in frames:
        lo, hi = np.searchsorted(kf, [frame.keyframe_id, frame.keyframe_id + 1])
        if hi == lo:
            continue
        feats = {c: v[lo:hi] for c, v in cols.items()}
        part = _keyframe_points(frame, feats, T_h_v, config, base, units)
        part["keyframe_id"] = np.full(len(part["range_m"]), frame.keyframe_id, np.int64)
        chunks.append(part)
    if not chunks:
        return FUSED_SCHEMA.empty_table()
    arrays = [pa.array(np.concatenate([c[f.name] for c in chunks])) for f in FUSED_SCHEMA]
    return pa.Table.from_arrays(arrays, schema=FUSED_SCHEMA)


def _keyframe_points(
    frame: KeyframeImages,
    feats: dict[str, np.ndarray],
    T_h_v: np.ndarray,
    config: FuseConfig,
    base: Mapping[str, Any],
    units: Units | None,
) -> dict[str, np.ndarray]:
    """`fuse_keyframe`, or its unit (the columns less keyframe_id)."""
    if units is None:
        return fuse_keyframe(frame, feats, T_h_v, config)
    pings = (frame.horizontal, frame.vertical)
    key = unit_key(
        {
            **base,
            "frame": array_digest(*(a for p in pings for a in (p.image, p.ranges_m, p.angles_rad))),
            "features": array_digest(*(feats[c] for c in sorted(feats) if c != "keyframe_id")),
        }
    )
    got = units.get(key)
    if got is not None:
        return {k: np.asarray(v) for k, v in got.items()}
    part = fuse_keyframe(frame, feats, T_h_v, config)
    units.put(key, part)
    return part


def run(config: FuseConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    """Stage entry point: keyframes.frames, keyframes.sensors, features.features (and the
    engine's "units") -> fused."""
    table = fuse_table(
        inputs["keyframes.frames"], inputs["features.features"], inputs["keyframes.sensors"],
        config, inputs.get(UNITS_INPUT),
    )  # fmt: skip
    return {"fused": table}
