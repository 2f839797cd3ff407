"""Stage `submaps`: dense submaps, mapping the ping pairs between keyframes too.

The paper maps SLAM keyframes only ("we do not analyze images between keyframes, due
to the high drift rate of our low-cost dead reckoning system", Sec. IV.A): at 2 m
spacing that is about one pair in eight. The authors' follow-up (McConnell,
Collado-Gonzalez, Szenher, Englot, "Large-Scale Dense 3D Mapping Using Submaps Derived
From Orthogonal Imaging Sonars", arXiv 2412.03760) integrates the frames between
keyframes into submaps anchored to them: dead reckoning is accurate over the 1-2 m to
the keyframe, and a frame moves with its keyframe when SLAM moves it.

Per keyframe, every `keyframes.submap_stride`-th pair recorded before the next one is a
submap frame (`sonarmap.stages.submaps.frames`, with T_kf_frame from dead reckoning). Each
frame, streamed from the recording one at a time, goes through what a keyframe goes
through, with the keyframe stages' own functions and config sections:

1. features: SOCA-CFAR on both images (`sonarmap.stages.kernels.frame_features`);
2. fuse: orthogonal stereo association, Eq. 3, 5, 6 (`sonarmap.stages.kernels.fusion`);
3. classify: the clusters of its horizontal returns (classify's own clustering, its
   output `clustering`) take the keyframe objects they see again
   (`sonarmap.stages.submaps.transfer`), instead of a CNN pass;
4. infer: its 2D-only returns on inferred classes are queried (Eq. 8-9) in the class
   models as they stand after the mission's last keyframe (infer's outputs
   `class_reference` and `class_cells`, read back, never relearned): the models learn
   from keyframes only, so the keyframe map is the same with or without submaps.

SLAM still uses keyframes only. `voxelize` registers a frame's points with
T_world_kf(SLAM) T_kf_frame T_base_sonar (Eq. 4 extended).

Frames are mapped in chunks of 64 (`sonarmap.stages.submaps.mapping`), here or, with
`submaps.workers` > 1, in that many processes (`sonarmap.stages.submaps.workers`).

Keys: the stride is in section `keyframes` but read only here (`Stage.key_excludes`),
so changing it recomputes `submaps`, `voxelize` and `evaluate`, nothing upstream; the
number of workers changes no byte and is in no key.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from sonarmap.schemas.classes import DEFAULT_TABLE
from sonarmap.schemas.recording import Recording
from sonarmap.schemas.sensors import Sensors
from sonarmap.schemas.submaps import (
    SUBMAP_FRAMES_SCHEMA,
    SUBMAP_POINTS_SCHEMA,
)
from sonarmap.stages.base import Input, StageInputError
from sonarmap.stages.kernels.class_models import (
    ClassModelSettings,
    ClassState,
    ModelTableError,
    restore_class_states,
)
from sonarmap.stages.kernels.clustering import clustering_params
from sonarmap.stages.kernels.front_end import thresholds
from sonarmap.stages.kernels.fusion import sonar_offset
from sonarmap.stages.kernels.pairing import interpolate_poses, posed_pairs
from sonarmap.stages.kernels.poses import pose_matrix
from sonarmap.stages.kernels.sightings import column, object_feature_rows
from sonarmap.stages.submaps import STAGE
from sonarmap.stages.submaps.config import READ_SECTIONS as _SECTIONS
from sonarmap.stages.submaps.config import SubmapsConfig
from sonarmap.stages.submaps.frames import submap_frame_rows
from sonarmap.stages.submaps.mapping import COUNTS, FRAMES_PER_CHUNK, FrameMapper
from sonarmap.stages.submaps.workers import mapped_chunks

__all__ = ["STAGE", "SubmapsConfig", "map_submap_frames"]


def _clustering(params: Mapping[str, Any]) -> tuple[float, int, int]:
    """The clustering classify used (its output `clustering`)."""
    if not isinstance(params, Mapping):
        raise StageInputError(Input("classify", "clustering"), "not a JSON object")
    try:
        checked = clustering_params(*(params[n] for n in ("eps_m", "min_samples", "min_features")))
    except KeyError as err:
        raise StageInputError(Input("classify", "clustering"), f"no {str(err)[:30]}") from err
    except (TypeError, ValueError) as err:
        raise StageInputError(Input("classify", "clustering"), str(err)) from err
    return checked["eps_m"], checked["min_samples"], checked["min_features"]


def map_submap_frames(
    rec: Recording,
    keyframes: pa.Table,
    sensors: Sensors | Mapping[str, Any],
    objects: pa.Table,
    object_features: pa.Table,
    features: pa.Table,
    fused: pa.Table,
    states: Mapping[str, ClassState],
    clustering: tuple[float, int, int],
    sections: Mapping[str, Any],
    config: SubmapsConfig,
    calibration: Mapping[str, Any] | None = None,
) -> tuple[pa.Table, pa.Table, dict[str, Any]]:
    """Frames, points and loss accounting of a mission's submaps (module docstring),
    `states` the class models infer learned (`restore_class_states`) and `clustering`
    (eps_m, min_samples, min_features) the one classify used, `calibration` the features
    stage's (`calibration.json`: the frames are detected with its thresholds; None: each
    frame calibrates itself).

    With `config.workers` > 1 the chunks of `FRAMES_PER_CHUNK` frames are mapped in
    that many processes (`sonarmap.stages.submaps.workers`); the outputs are the same bytes.
    """
    kcfg = sections["keyframes"]
    icfg: ClassModelSettings = sections["infer"]
    stride = kcfg.submap_stride
    empty_stats: dict[str, Any] = {"stride": stride, "frames": 0, "classes": {}}
    if stride == 0:
        return SUBMAP_FRAMES_SCHEMA.empty_table(), SUBMAP_POINTS_SCHEMA.empty_table(), empty_stats
    posed = posed_pairs(rec, kcfg.pair_tolerance_s)
    pair_rows = posed.posed
    h_idx = posed.pairs.horizontal[pair_rows]
    v_idx = posed.pairs.vertical[pair_rows]
    truth = rec.ground_truth()
    gt = None if truth is None else interpolate_poses(truth, posed.h_t_ns[h_idx])[0]
    frames = submap_frame_rows(
        column(keyframes, "ping_index_horizontal", "keyframes"),
        h_idx, v_idx, posed.h_t_ns, posed.v_t_ns, posed.pose[pair_rows], gt, stride,
    )  # fmt: skip
    horizontal = features.filter(pc.equal(features.column("sonar"), "horizontal"))
    mapper = FrameMapper(
        features=sections["features"],
        thresholds=_thresholds(calibration),
        fuse=sections["fuse"],
        infer=icfg,
        clustering=clustering,
        match_radius_m=config.match_radius_m or clustering[0],
        next_keyframe_objects=config.next_keyframe_objects,
        object_rows=object_feature_rows(objects, object_features, horizontal, fused),
        class_of=dict(
            zip(
                column(objects, "object_id", "objects").tolist(),
                column(objects, "class_name", "objects").tolist(),
                strict=True,
            )
        ),
        states=states,
        T_base_sonar=Sensors.of(sensors).horizontal.T_base_sonar,
        T_h_v=sonar_offset(sensors),
        kf_pose=_pose_matrices(keyframes, "keyframes"),
        frame_pose=_pose_matrices(frames, "submap frames"),
        frame_keyframe=frames.column("keyframe_id").to_numpy(),
        ping_horizontal=frames.column("ping_index_horizontal").to_numpy(),
        ping_vertical=frames.column("ping_index_vertical").to_numpy(),
    )
    chunks = [
        (first, min(first + FRAMES_PER_CHUNK, frames.num_rows))
        for first in range(0, frames.num_rows, FRAMES_PER_CHUNK)
    ]
    funnels: dict[str, dict[str, int]] = {}
    counts = dict.fromkeys(COUNTS, 0)
    tables: list[pa.Table] = [SUBMAP_POINTS_SCHEMA.empty_table()]
    for chunk in mapped_chunks(mapper, rec, chunks, config.workers):
        tables.append(chunk.points)
        for name, n in chunk.counts.items():
            counts[name] += n
        for c, steps in chunk.funnels.items():
            total = funnels.setdefault(c, dict.fromkeys(steps, 0))
            for step, n in steps.items():
                total[step] += n
    stats = {
        **empty_stats,
        "frames": frames.num_rows,
        **counts,
        "classes": dict(sorted(funnels.items())),
    }
    return frames, pa.concat_tables(tables), stats


def _thresholds(calibration: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """Per sonar, the thresholds of the features stage's calibration."""
    if calibration is None:
        return None
    try:
        return thresholds(dict(calibration))
    except (KeyError, TypeError, ValueError) as err:
        raise StageInputError(Input("features", "calibration"), f"unreadable: {err}") from err


def _pose_matrices(table: pa.Table, what: str) -> np.ndarray:
    return pose_matrix(np.stack([column(table, c, what) for c in _POSE], axis=1).astype(np.float64))


_POSE = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")


def _infer_section(inputs: Mapping[str, Any]) -> Any:
    """Section `infer` resolved with the class table (`InferConfig.with_table`)."""
    return inputs["config.infer"].with_table(inputs.get("config.classes", DEFAULT_TABLE))


def _class_states(inputs: Mapping[str, Any]) -> dict[str, ClassState]:
    try:
        return restore_class_states(
            inputs["infer.class_reference"], inputs["infer.class_cells"], _infer_section(inputs)
        )
    except ModelTableError as err:
        raise StageInputError(Input("infer", err.output), err.reason) from err


def _run(config: SubmapsConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    frames, points, stats = map_submap_frames(
        inputs["dataset"],
        inputs["keyframes.keyframes"],
        inputs["keyframes.sensors"],
        inputs["classify.objects"],
        inputs["classify.object_features"],
        inputs["features.features"],
        inputs["fuse.fused"],
        _class_states(inputs),
        _clustering(inputs["classify.clustering"]),
        {**{s: inputs[f"config.{s}"] for s in _SECTIONS}, "infer": _infer_section(inputs)},
        config,
        inputs.get("features.calibration"),
    )
    return {"frames": frames, "points": points, "stats": stats}
