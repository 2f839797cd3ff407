"""One submap frame mapped: features, fusion, classes from the keyframe objects it sees
again, and height queries (`sonarmap.stages.submaps.stage`'s steps 1-4), in chunks of frames.

`FrameMapper` holds everything a frame's mapping reads besides the frame's own images;
it pickles, so worker processes (`sonarmap.stages.submaps.workers`) map chunks with the very code
that maps them in the stage's own process.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.schemas.map import NO_CLASS
from sonarmap.schemas.recording import Recording
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.schemas.submaps import SUBMAP_POINTS_SCHEMA, SUBMAP_POINTS_SORT_KEYS
from sonarmap.stages.kernels.class_models import ClassModelSettings, ClassState, inferred_classes
from sonarmap.stages.kernels.class_query import (
    Funnel,
    borrowed_sightings,
    register_and_query,
    update_and_query_beam_class,
)
from sonarmap.stages.kernels.frame_features import CfarSettings, keyframe_features
from sonarmap.stages.kernels.front_end import BandThresholds
from sonarmap.stages.kernels.fusion import FusionSettings, fuse_keyframe
from sonarmap.stages.kernels.point_tables import points_table, tag_points
from sonarmap.stages.kernels.sightings import sightings
from sonarmap.stages.submaps.transfer import KeyframeObjectPoints, transfer_objects

__all__ = ["COUNTS", "FRAMES_PER_CHUNK", "FrameMapper", "MappedChunk", "frame_points"]

_FUSED_COLUMNS = ("range_m", "bearing_rad", "elevation_rad", "x_m", "y_m", "z_m", "confidence")


class _KeyframeObjects:
    """The keyframes' object returns, indexed per keyframe, built as frames need them."""

    def __init__(self, rows: dict[str, np.ndarray]) -> None:
        self.rows = rows
        kf = rows["keyframe_id"]
        self.ids, self.starts = np.unique(kf, return_index=True)
        self.ends = np.r_[self.starts[1:], kf.size]
        self.cache: dict[int, KeyframeObjectPoints] = {}

    def objects(self, keyframe_id: int) -> KeyframeObjectPoints:
        if keyframe_id not in self.cache:
            if len(self.cache) > 4:
                self.cache.pop(min(self.cache))
            i = np.searchsorted(self.ids, keyframe_id)
            if i < self.ids.size and self.ids[i] == keyframe_id:
                sl = slice(int(self.starts[i]), int(self.ends[i]))
                r, t = self.rows["range_m"][sl], self.rows["bearing_rad"][sl]
                xy = np.stack([r * np.cos(t), r * np.sin(t)], axis=1)
                self.cache[keyframe_id] = KeyframeObjectPoints(xy, self.rows["object_id"][sl])
            else:
                self.cache[keyframe_id] = KeyframeObjectPoints(np.empty((0, 2)), np.empty(0))
        return self.cache[keyframe_id]


def _query(
    sights: list,
    states: Mapping[str, ClassState],
    config: ClassModelSettings,
    funnels: dict[str, Funnel],
) -> list[tuple[dict[str, np.ndarray], np.ndarray, str]]:
    """Eq. 8-9 for one frame's sightings, models unchanged: (points, object ids, class)."""
    found = []
    for c in inferred_classes(config):
        state = states[c]
        funnels.setdefault(c, Funnel())
        if not state.model.updated:
            continue
        beam = config.frame_kind(c) == "beam"
        groups = [(c, [s for s in sights if s.class_name == c])]
        groups += borrowed_sightings(c, sights, config)
        for name, group in groups:
            if not group:
                continue
            funnel = funnels.setdefault(name, Funnel())
            funnel.counts["objects"] += len(group)
            funnel.counts["returns"] += sum(s.range_m.size for s in group)
            funnel.counts["fused_returns"] += sum(int(s.is_fused.sum()) for s in group)
            if beam:
                res = update_and_query_beam_class(state, group, config, funnel, update=False)
            else:
                res = register_and_query(state, group, config, funnel)
            if res is not None:
                found.append((res[0], res[1], name))
    return found


@dataclass(frozen=True)
class FrameMapper:
    """What mapping a submap frame reads (module docstring, steps 1-4), frames aside.

    It pickles (numpy arrays, config models, class models), so worker processes map
    chunks of frames with the very code that maps them here.
    """

    features: CfarSettings
    thresholds: Mapping[str, BandThresholds] | None
    fuse: FusionSettings
    infer: ClassModelSettings
    clustering: tuple[float, int, int]
    match_radius_m: float
    next_keyframe_objects: bool
    object_rows: dict[str, np.ndarray]
    class_of: dict[int, str]
    states: Mapping[str, ClassState]
    T_base_sonar: np.ndarray
    T_h_v: np.ndarray
    kf_pose: np.ndarray
    frame_pose: np.ndarray
    frame_keyframe: np.ndarray
    ping_horizontal: np.ndarray
    ping_vertical: np.ndarray

    def map_chunk(self, rec: Recording, first: int, stop: int) -> MappedChunk:
        """Points (sorted), counts and funnels of frames first..stop-1, streamed."""
        eps, min_samples, min_features = self.clustering
        M = self.T_base_sonar
        M_inv = np.linalg.inv(M)
        kf_objects = _KeyframeObjects(self.object_rows)
        funnels: dict[str, Funnel] = {}
        counts = dict.fromkeys(COUNTS, 0)
        parts: list[dict[str, Any]] = []
        pings = zip(
            rec.pings("horizontal", self.ping_horizontal[first:stop], labels=False),
            rec.pings("vertical", self.ping_vertical[first:stop], labels=False),
            strict=True,
        )
        for frame_id, (hp, vp) in enumerate(pings, start=first):
            k = int(self.frame_keyframe[frame_id])
            image = KeyframeImages(frame_id, int(hp.t_ns), hp, vp, {})
            feats = keyframe_features(image, self.features, self.thresholds)
            feats["is_horizontal"] = feats["sonar_index"] == 0
            fu = fuse_keyframe(image, feats, self.T_h_v, self.fuse)
            is_h = feats["is_horizontal"]
            candidates = (
                [k, k + 1] if self.next_keyframe_objects and k + 1 < len(self.kf_pose) else [k]
            )
            transforms = [
                M_inv @ np.linalg.inv(self.kf_pose[c]) @ self.frame_pose[frame_id] @ M
                for c in candidates
            ]
            oid = transfer_objects(
                feats["range_m"][is_h], feats["angle_rad"][is_h], transforms,
                [kf_objects.objects(c) for c in candidates], eps, min_samples, min_features,
                self.match_radius_m,
            )  # fmt: skip
            counts["horizontal_returns"] += int(is_h.sum())
            counts["clustered_assigned_returns"] += int((oid >= 0).sum())
            counts["fused_points"] += int(fu["range_m"].size)
            parts.extend(
                frame_points(
                    frame_id, k, feats, is_h, oid, fu, self.class_of, self.states, self.infer,
                    funnels,
                )
            )  # fmt: skip
        table = points_table(parts, SUBMAP_POINTS_SCHEMA, SUBMAP_POINTS_SORT_KEYS)
        return MappedChunk(table, counts, {c: dict(f.counts) for c, f in funnels.items()})


@dataclass(frozen=True)
class MappedChunk:
    """A chunk of frames mapped: its sorted points, counts and per-class funnel counts."""

    points: pa.Table
    counts: dict[str, int]
    funnels: dict[str, dict[str, int]]


COUNTS = ("horizontal_returns", "clustered_assigned_returns", "fused_points")
FRAMES_PER_CHUNK = 64
"""Frames mapped, and their points sorted, together: rows sort by frame first, so the
sorted chunks concatenate in order and the points exist once, not once per
concatenation and once sorted. Also the unit of work of a worker process."""


def frame_points(
    frame_id: int,
    keyframe_id: int,
    feats: dict[str, np.ndarray],
    is_h: np.ndarray,
    oid: np.ndarray,
    fu: dict[str, np.ndarray],
    class_of: Mapping[int, str],
    states: Mapping[str, ClassState],
    icfg: ClassModelSettings,
    funnels: dict[str, Funnel],
) -> list[dict[str, Any]]:
    """Fused and inferred point parts of one submap frame (`points_table` rows).

    Args:
        feats: the frame's features (`keyframe_features` columns plus `is_horizontal`);
            is_h: that mask; oid: (n_horizontal,) object of each horizontal return (-1:
            none; `transfer_objects`); fu: its fused points (`fuse_keyframe`).
        class_of: class name of every keyframe object id.
        states: the class models; funnels: loss accounting, updated in place.
    """
    fid = feats["feature_id"][is_h]
    fused_cols = {c: np.asarray(fu[c], np.float64) for c in _FUSED_COLUMNS}
    # object of each fused point: that of its horizontal return
    fused_obj = oid[np.searchsorted(fid, fu["feature_id_horizontal"])] if fid.size else oid
    parts = []
    for obj in np.unique(fused_obj):
        sel = fused_obj == obj
        name = class_of.get(int(obj), NO_CLASS) if obj >= 0 else NO_CLASS
        pts = {c: v[sel] for c, v in fused_cols.items()}
        parts.append(_tag(tag_points(pts, keyframe_id, int(obj), name, "fused"), frame_id))
    assigned = np.flatnonzero(oid >= 0)
    if assigned.size == 0:
        return parts
    order = assigned[np.lexsort((fid[assigned], oid[assigned]))]
    objects, of_row = np.unique(oid[order], return_inverse=True)
    object_names = np.array([class_of.get(int(o), NO_CLASS) for o in objects])
    names = np.unique(object_names)
    fused_row = np.full(fid.size, -1, np.int64)
    fused_row[np.searchsorted(fid, fu["feature_id_horizontal"])] = np.arange(fu["range_m"].size)
    rows = {
        "keyframe_id": np.full(order.size, frame_id, np.int64),
        "object_id": oid[order],
        "class_index": np.searchsorted(names, object_names)[of_row.reshape(-1)],
        "range_m": feats["range_m"][is_h][order],
        "bearing_rad": feats["angle_rad"][is_h][order],
        "beam": feats["beam"][is_h][order],
        "fused_row": fused_row[order],
        "classes": names,
    }
    sights = sightings(rows, slice(0, order.size), fused_cols)
    for pts, objs, c in _query(sights, states, icfg, funnels):
        parts.append(_tag(tag_points(pts, keyframe_id, objs, c, "inferred"), frame_id))
    return parts


def _tag(part: dict[str, Any], frame_id: int) -> dict[str, Any]:
    part["frame_id"] = np.full(part["range_m"].size, frame_id, np.int64)
    return part
