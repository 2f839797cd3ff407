"""Stage `submaps`: dense submaps, mapping the ping pairs between keyframes too.

The paper maps SLAM keyframes only ("we do not analyze images between keyframes, due
to the high drift rate of our low-cost dead reckoning system", Sec. IV.A): at 2 m
spacing that is about one pair in eight. The authors' follow-up (McConnell,
Collado-Gonzalez, Szenher, Englot, "Large-Scale Dense 3D Mapping Using Submaps Derived
From Orthogonal Imaging Sonars", arXiv 2412.03760) integrates the frames between
keyframes into submaps anchored to them: dead reckoning is accurate over the 1-2 m to
the keyframe, and a frame moves with its keyframe when SLAM moves it.

Per keyframe, every `keyframes.submap_stride`-th pair recorded before the next one is a
submap frame (`stages.submaps.frames`, with T_kf_frame from dead reckoning). Each
frame, streamed from the recording one at a time, goes through what a keyframe goes
through, with the keyframe stages' own functions and config sections:

1. features: SOCA-CFAR on both images (`stages.features.stage.keyframe_features`);
2. fuse: orthogonal stereo association, Eq. 3, 5, 6 (`stages.fuse.stage.fuse_keyframe`);
3. classify: the clusters of its horizontal returns take the keyframe objects they see
   again (`stages.submaps.transfer`), instead of a CNN pass;
4. infer: its 2D-only returns on inferred classes are queried (Eq. 8-9) in the class
   models as they stand after the mission's last keyframe (`learn_and_infer`): the
   models learn from keyframes only, so the keyframe map is the same with or without
   submaps.

SLAM still uses keyframes only. `voxelize` registers a frame's points with
T_world_kf(SLAM) T_kf_frame T_base_sonar (Eq. 4 extended).

Keys: the stride is in section `keyframes` but read only here (`Stage.key_excludes`),
so changing it recomputes `submaps`, `voxelize` and `evaluate`, nothing upstream.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from schemas.map import NO_CLASS
from schemas.recording import Recording
from schemas.sonar import KeyframeImages
from schemas.submaps import (
    SUBMAP_FRAMES_SCHEMA,
    SUBMAP_POINTS_SCHEMA,
    SUBMAP_POINTS_SORT_KEYS,
)
from stages.base import Output, Stage
from stages.classify.stage import ClassifyConfig
from stages.features.stage import FeaturesConfig, keyframe_features
from stages.fuse.stage import FuseConfig, fuse_keyframe, sonar_offset
from stages.infer.config import InferConfig
from stages.infer.inputs import column, object_feature_rows, sightings
from stages.infer.prediction import (
    ClassState,
    Funnel,
    borrowed_sightings,
    register_and_query,
    update_and_query_beam_class,
)
from stages.infer.stage import learn_and_infer, points_table, tag_points
from stages.keyframes import KeyframesConfig, interpolate_poses, posed_pairs
from stages.submaps.config import SubmapsConfig
from stages.submaps.frames import submap_frame_rows
from stages.submaps.transfer import KeyframeObjectPoints, transfer_objects
from stages.voxelize.registration import pose_matrix

__all__ = ["STAGE", "SubmapsConfig", "frame_points", "map_submap_frames"]

_FUSED_COLUMNS = ("range_m", "bearing_rad", "elevation_rad", "x_m", "y_m", "z_m", "confidence")
_SECTIONS = ("keyframes", "features", "fuse", "classify", "infer", "train")


def _clustering(classify: ClassifyConfig, train: Any) -> tuple[float, int, int]:
    """The classifier's clustering: classify's overrides, else the training section's."""
    pick = [getattr(classify, n) for n in ("eps_m", "min_samples", "min_features")]
    eps, samples, feats = (
        v if v is not None else getattr(train, n)
        for v, n in zip(pick, ("eps_m", "min_samples", "min_features"), strict=True)
    )
    return float(eps), int(samples), int(feats)


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
    config: InferConfig,
    funnels: dict[str, Funnel],
) -> list[tuple[dict[str, np.ndarray], np.ndarray, str]]:
    """Eq. 8-9 for one frame's sightings, models unchanged: (points, object ids, class)."""
    found = []
    for c in config.classes:
        state = states[c]
        funnels.setdefault(c, Funnel())
        if not state.model.updated:
            continue
        beam = config.frame_kind(c) == "beam"
        groups = [(c, [s for s in sights if s.class_name == c])]
        if beam:
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


def map_submap_frames(
    rec: Recording,
    keyframes: pa.Table,
    sensors: Mapping[str, Any],
    objects: pa.Table,
    object_features: pa.Table,
    features: pa.Table,
    fused: pa.Table,
    sections: Mapping[str, Any],
    config: SubmapsConfig,
) -> tuple[pa.Table, pa.Table, dict[str, Any]]:
    """Frames, points and loss accounting of a mission's submaps (module docstring)."""
    kcfg: KeyframesConfig = sections["keyframes"]
    fcfg: FeaturesConfig = sections["features"]
    ucfg: FuseConfig = sections["fuse"]
    icfg: InferConfig = sections["infer"]
    eps, min_samples, min_features = _clustering(sections["classify"], sections["train"])
    radius = config.match_radius_m or eps
    stride = kcfg.submap_stride
    empty_stats: dict[str, Any] = {"stride": stride, "frames": 0, "classes": {}}
    if stride == 0:
        return SUBMAP_FRAMES_SCHEMA.empty_table(), SUBMAP_POINTS_SCHEMA.empty_table(), empty_stats
    posed = posed_pairs(rec, kcfg)
    pair_rows = posed.posed
    h_idx = posed.pairs.horizontal[pair_rows]
    v_idx = posed.pairs.vertical[pair_rows]
    truth = rec.ground_truth()
    gt = None if truth is None else interpolate_poses(truth, posed.h_t_ns[h_idx])[0]
    frames = submap_frame_rows(
        column(keyframes, "ping_index_horizontal", "keyframes"),
        h_idx, v_idx, posed.h_t_ns, posed.v_t_ns, posed.pose[pair_rows], gt, stride,
    )  # fmt: skip
    _, _, states = learn_and_infer(objects, object_features, features, fused, icfg, query=False)
    horizontal = features.filter(pc.equal(features.column("sonar"), "horizontal"))
    kf_objects = _KeyframeObjects(object_feature_rows(objects, object_features, horizontal, fused))
    class_of = dict(
        zip(
            column(objects, "object_id", "objects").tolist(),
            column(objects, "class_name", "objects").tolist(),
            strict=True,
        )
    )
    M = np.asarray(sensors["horizontal"]["T_base_sonar"], np.float64)
    M_inv = np.linalg.inv(M)
    T_h_v = sonar_offset(sensors)
    kf_pose = pose_matrix(
        np.stack([column(keyframes, c, "keyframes") for c in _POSE], axis=1).astype(np.float64)
    )
    fr_pose = pose_matrix(
        np.stack([frames.column(c).to_numpy() for c in _POSE], axis=1).astype(np.float64)
    )
    fr_kf = frames.column("keyframe_id").to_numpy()
    funnels: dict[str, Funnel] = {}
    counts = {"horizontal_returns": 0, "clustered_assigned_returns": 0, "fused_points": 0}
    parts: list[dict[str, Any]] = []
    tables: list[pa.Table] = []
    pings = zip(
        rec.pings("horizontal", frames.column("ping_index_horizontal").to_numpy(), labels=False),
        rec.pings("vertical", frames.column("ping_index_vertical").to_numpy(), labels=False),
        strict=True,
    )
    for frame_id, (hp, vp) in enumerate(pings):
        k = int(fr_kf[frame_id])
        image = KeyframeImages(frame_id, int(hp.t_ns), hp, vp, {})
        feats = keyframe_features(image, fcfg)
        feats["is_horizontal"] = feats["sonar_index"] == 0
        fu = fuse_keyframe(image, feats, T_h_v, ucfg)
        is_h = feats["is_horizontal"]
        candidates = [k, k + 1] if config.next_keyframe_objects and k + 1 < len(kf_pose) else [k]
        transforms = [M_inv @ np.linalg.inv(kf_pose[c]) @ fr_pose[frame_id] @ M for c in candidates]
        oid = transfer_objects(
            feats["range_m"][is_h], feats["angle_rad"][is_h], transforms,
            [kf_objects.objects(c) for c in candidates], eps, min_samples, min_features, radius,
        )  # fmt: skip
        counts["horizontal_returns"] += int(is_h.sum())
        counts["clustered_assigned_returns"] += int((oid >= 0).sum())
        counts["fused_points"] += int(fu["range_m"].size)
        parts.extend(
            frame_points(frame_id, k, feats, is_h, oid, fu, class_of, states, icfg, funnels)
        )
        if (frame_id + 1) % _FRAMES_PER_TABLE == 0:
            # rows sort by frame first, so sorted batches of frames concatenate in order
            # and the points exist once, not once per concatenation and once sorted
            tables.append(points_table(parts, SUBMAP_POINTS_SCHEMA, SUBMAP_POINTS_SORT_KEYS))
            parts = []
    tables.append(points_table(parts, SUBMAP_POINTS_SCHEMA, SUBMAP_POINTS_SORT_KEYS))
    points = pa.concat_tables(tables)
    stats = {
        **empty_stats,
        "frames": frames.num_rows,
        **counts,
        "classes": {c: dict(f.counts) for c, f in sorted(funnels.items())},
    }
    return frames, points, stats


_POSE = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
_FRAMES_PER_TABLE = 64


def frame_points(
    frame_id: int,
    keyframe_id: int,
    feats: dict[str, np.ndarray],
    is_h: np.ndarray,
    oid: np.ndarray,
    fu: dict[str, np.ndarray],
    class_of: Mapping[int, str],
    states: Mapping[str, ClassState],
    icfg: InferConfig,
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


def _run(config: SubmapsConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    frames, points, stats = map_submap_frames(
        inputs["dataset"],
        inputs["keyframes.keyframes"],
        inputs["keyframes.sensors"],
        inputs["classify.objects"],
        inputs["classify.object_features"],
        inputs["features.features"],
        inputs["fuse.fused"],
        {s: inputs[f"config.{s}"] for s in _SECTIONS},
        config,
    )
    return {"frames": frames, "points": points, "stats": stats}


STAGE = Stage(
    name="submaps",
    # 2: points written in sorted batches of 64 frames (same rows, other Parquet pages)
    # 3: classes that borrow a beam-frame model (infer.borrowed_models, unknown_argmax_classes)
    version=3,
    config=SubmapsConfig,
    inputs=(
        "dataset",
        "keyframes.keyframes",
        "keyframes.sensors",
        "classify.objects",
        "classify.object_features",
        "features.features",
        "fuse.fused",
    ),
    outputs=(
        Output("frames", "parquet", "submap_frames.parquet", schema=SUBMAP_FRAMES_SCHEMA),
        Output("points", "parquet", "submap_points.parquet", schema=SUBMAP_POINTS_SCHEMA),
        Output("stats", "json", "stats.json"),
    ),
    run=_run,
    description="dense submaps: the ping pairs between keyframes, anchored to their keyframe",
    reads_sections=_SECTIONS,
    dataset_section="keyframes",
)
