"""Object sightings of the class models: object features joined to their features and
fused points, grouped into per-keyframe (or per-frame) object sightings (vectorised),
for stage `infer` (keyframes) and stage `submaps` (the frames between them)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from sonarmap.stages.kernels.geometry import fan_to_xy
from sonarmap.stages.kernels.object_frame import ObjectOrigin

__all__ = [
    "FUSED_FEATURE_COLUMN",
    "Sighting",
    "column",
    "object_feature_rows",
    "sightings",
]

FUSED_FEATURE_COLUMN = "feature_id_horizontal"
"""Column of `fuse.fused` naming the horizontal feature of a fused point."""


@dataclass
class Sighting:
    """One object in one keyframe: its 2D returns and fused points (object frame)."""

    object_id: int
    class_name: str
    origin: ObjectOrigin
    uv_m: np.ndarray  # (n, 2) all 2D returns
    range_m: np.ndarray  # (n,)
    bearing_rad: np.ndarray  # (n,)
    beam: np.ndarray  # (n,) horizontal beam index
    is_fused: np.ndarray  # (n,) bool
    fused_uv_m: np.ndarray  # (k, 2)
    fused_z_m: np.ndarray  # (k,)
    fused_rows: np.ndarray  # (k,) rows of the fused table
    argmax_class_name: str = ""  # the classifier's arg-max class ("" when not known)

    @property
    def extent_m(self) -> float:
        """Diagonal of the sonar-frame bounding box of the object's 2D returns."""
        x = self.range_m * np.cos(self.bearing_rad)
        y = self.range_m * np.sin(self.bearing_rad)
        return float(np.hypot(np.ptp(x), np.ptp(y))) if x.size else 0.0


def _key(keyframe_id: np.ndarray, feature_id: np.ndarray) -> np.ndarray:
    """Packed int64 (keyframe_id, feature_id) join key."""
    return np.asarray(keyframe_id, dtype=np.int64) * (1 << 32) + np.asarray(
        feature_id, dtype=np.int64
    )


def column(table: pa.Table, name: str, what: str) -> np.ndarray:
    if name not in table.column_names:
        raise ValueError(f"infer: input {what} lacks column {name!r}")
    return table.column(name).to_numpy(zero_copy_only=False)


def _lookup(keys_sorted: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Index of each key in a sorted unique key array, -1 where absent."""
    if keys_sorted.size == 0:
        return np.full(keys.size, -1, dtype=np.int64)
    pos = np.minimum(np.searchsorted(keys_sorted, keys), keys_sorted.size - 1)
    return np.where(keys_sorted[pos] == keys, pos, -1)


def object_feature_rows(
    objects: pa.Table, object_features: pa.Table, features: pa.Table, fused: pa.Table
) -> dict[str, np.ndarray]:
    """Join object features to their feature rows and fused points (vectorised).

    Returns arrays over object-feature rows sorted by (keyframe, object, feature):
    keyframe_id, object_id, class_index and argmax_index (the arg-max class, into
    `classes`), range_m, bearing_rad, fused_row (-1 for a 2D-only return), plus
    `classes` (unique class names).
    """
    of_kf = column(object_features, "keyframe_id", "object_features").astype(np.int64)
    of_obj = column(object_features, "object_id", "object_features").astype(np.int64)
    of_fid = column(object_features, "feature_id", "object_features").astype(np.int64)
    order = np.lexsort((of_fid, of_obj, of_kf))
    of_kf, of_obj, of_fid = of_kf[order], of_obj[order], of_fid[order]
    # Feature geometry (horizontal sonar: angle = bearing).
    f_key = _key(
        column(features, "keyframe_id", "features"), column(features, "feature_id", "features")
    )
    f_order = np.argsort(f_key, kind="stable")
    f_row = _lookup(f_key[f_order], _key(of_kf, of_fid))
    if (f_row < 0).any():
        raise ValueError("infer: object_features references features that do not exist")
    f_row = f_order[f_row]
    # Class of each object.
    o_key = _key(column(objects, "keyframe_id", "objects"), column(objects, "object_id", "objects"))
    o_order = np.argsort(o_key, kind="stable")
    o_row = _lookup(o_key[o_order], _key(of_kf, of_obj))
    if (o_row < 0).any():
        raise ValueError("infer: object_features references objects that do not exist")
    names = np.asarray(column(objects, "class_name", "objects"), dtype=str)
    argmax = (
        np.asarray(column(objects, "argmax_class_name", "objects"), dtype=str)
        if "argmax_class_name" in objects.column_names
        else names
    )
    classes, codes = np.unique(np.concatenate([names, argmax]), return_inverse=True)
    class_index, argmax_index = codes.reshape(-1)[: names.size], codes.reshape(-1)[names.size :]
    # Fused point of each horizontal feature (if any).
    fu_key = _key(
        column(fused, "keyframe_id", "fused"), column(fused, FUSED_FEATURE_COLUMN, "fused")
    )
    fu_order = np.argsort(fu_key, kind="stable")
    fu_row = _lookup(fu_key[fu_order], _key(of_kf, of_fid))
    return {
        "keyframe_id": of_kf,
        "object_id": of_obj,
        "class_index": class_index[o_order[o_row]],
        "argmax_index": argmax_index[o_order[o_row]],
        "range_m": column(features, "range_m", "features").astype(np.float64)[f_row],
        "bearing_rad": column(features, "angle_rad", "features").astype(np.float64)[f_row],
        "beam": _beams(features)[f_row],
        "fused_row": np.where(fu_row >= 0, np.r_[fu_order, -1][fu_row], -1),
        "classes": classes,
    }


def _beams(features: pa.Table) -> np.ndarray:
    """Horizontal beam index of every feature (from its bearing when there is no `beam`)."""
    if "beam" in features.column_names:
        return column(features, "beam", "features").astype(np.int64)
    bearing = column(features, "angle_rad", "features")
    return np.unique(bearing, return_inverse=True)[1].reshape(-1).astype(np.int64)


def sightings(rows: dict[str, np.ndarray], sl: slice, fused: dict[str, np.ndarray]) -> list:
    """Sightings of one keyframe (rows[sl], grouped by object id), sorted by object id.

    Origins (minimum range, median bearing) and object-frame coordinates are computed
    for all rows of the keyframe at once; each sighting holds its slices.
    """
    obj = rows["object_id"][sl]
    if obj.size == 0:
        return []
    starts = np.flatnonzero(np.r_[True, np.diff(obj) != 0])
    ends = np.r_[starts[1:], obj.size]
    r, t = rows["range_m"][sl], rows["bearing_rad"][sl]
    group = np.repeat(np.arange(starts.size), ends - starts)
    min_range = np.minimum.reduceat(r, starts)
    # median bearing per object: the middle one or two of its sorted bearings
    t_sorted = t[np.lexsort((t, group))]
    median = 0.5 * (
        t_sorted[starts + (ends - starts - 1) // 2] + t_sorted[starts + (ends - starts) // 2]
    )
    d = t - median[group]
    # Eq. 1 (phi = 0) in each object's frame: rotated by its median bearing, shifted by its
    # nearest range along u.
    uv = fan_to_xy(r, d) - np.column_stack([min_range[group], np.zeros(d.size)])
    fused_row = rows["fused_row"][sl]
    is_fused = fused_row >= 0
    fr_all = fused_row[is_fused]
    fr_group = group[is_fused]
    fd = fused["bearing_rad"][fr_all] - median[fr_group]
    fr_range = fused["range_m"][fr_all]
    fused_uv = np.stack(
        [fr_range * np.cos(fd) - min_range[fr_group], fr_range * np.sin(fd)], axis=1
    )
    fused_bounds = np.searchsorted(fr_group, np.arange(starts.size + 1))
    out = []
    for g, (a, b) in enumerate(zip(starts, ends, strict=True)):
        fa, fb = fused_bounds[g], fused_bounds[g + 1]
        out.append(
            Sighting(
                object_id=int(obj[a]),
                class_name=str(rows["classes"][rows["class_index"][sl.start + a]]),
                argmax_class_name=str(
                    rows["classes"][rows.get("argmax_index", rows["class_index"])[sl.start + a]]
                ),
                origin=ObjectOrigin(float(min_range[g]), float(median[g])),
                uv_m=uv[a:b],
                range_m=r[a:b],
                bearing_rad=t[a:b],
                beam=rows["beam"][sl][a:b],
                is_fused=is_fused[a:b],
                fused_uv_m=fused_uv[fa:fb],
                fused_z_m=fused["z_m"][fr_all[fa:fb]],
                fused_rows=fr_all[fa:fb],
            )
        )
    return out
