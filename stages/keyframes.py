"""Keyframes: pair the two sonars in time, pose each pair, keep pairs by spacing.

Pure logic over arrays; the recording (a `schemas.recording.Recording`, bound by the
engine as the "dataset" input) supplies ping times, the navigation stream and, for the
selected keyframes only, the decoded images, so memory stays flat in mission length.

Steps:
1. Pair every horizontal ping with the nearest vertical ping within
   `pair_tolerance_s` (each vertical ping used at most once).
2. Interpolate the navigation pose at each pair's time (the horizontal ping time):
   SE(2) (x, y, yaw on the shortest arc) plus depth z, roll and pitch linearly; pairs
   outside the navigation stream are dropped, never extrapolated.
3. Keep a pair as keyframe when, since the last keyframe, at least `min_gap_s` has
   passed and the vehicle has moved `spacing_m` (3D distance) or turned `rotation_deg`
   (|delta yaw|); the first posed pair is always kept (the paper keeps keyframes every
   2 m or 4 m; the authors' rule in original-implementation.md section 6.2).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping
from typing import Annotated, Any

import numpy as np
import pyarrow as pa
from pydantic import Field

from schemas.keyframes import GT_POSE_COLUMNS, KEYFRAMES_SCHEMA, POSE_COLUMNS
from schemas.recording import Recording
from schemas.sensors import Sensors
from schemas.sonar import KeyframeImages
from stages.base import DATASET, Output, Stage, StageConfig, StageInputError
from stages.kernels.pairing import (
    PingPairs,
    PosedPairs,
    interpolate_poses,
    pair_pings,
    posed_pairs,
)
from stages.kernels.sonar_geometry import sonar_geometry

__all__ = [
    "STAGE",
    "KeyframesConfig",
    "PingPairs",
    "PosedPairs",
    "interpolate_poses",
    "pair_pings",
    "posed_pairs",
    "select_keyframes",
]


log = logging.getLogger(__name__)


_MountM = Annotated[float, Field(ge=-100.0, le=100.0)]
_MountDeg = Annotated[float, Field(ge=-360.0, le=360.0)]


class KeyframesConfig(StageConfig):
    """Config section `keyframes`.

    Attributes:
        spacing_m: new keyframe after this much travel (3D) since the last one [m].
        rotation_deg: ... or after this much |yaw change| [deg].
        min_gap_s: never two keyframes closer in time than this [s].
        pair_tolerance_s: largest |t_h - t_v| of a sonar pair [s].
        horizontal_topic, vertical_topic: sonar topics (None: found by type/name).
        navigation_topic: Odometry/PoseStamped/PoseWithCovarianceStamped topic (None: found).
        ground_truth_topic: true pose topic (None: /ground_truth/odometry if present).
        dvl_topic, imu_topic: dead-reckoning inputs when no navigation topic.
        depth_topic: depth source (FluidPressure, a `depth` field, or a pose's z); with a
            navigation topic it replaces the navigation's z.
        dvl_max_velocity_mps: DVL samples faster than this are dropped as implausible [m/s]
            (a limit well above vehicle speed; the drops are counted and reported).
        water_density_kg_m3, gravity_m_s2: depth from pressure, (p - p_surface) / (rho g).
        surface_pressure_pa: p_surface [Pa] (None: from `surface_pressure_from_first_s`,
            else one standard atmosphere).
        surface_pressure_from_first_s: take p_surface as the median pressure of the
            recording's first seconds (the vehicle at the surface).
        image_fov_deg, image_max_range_m: beam table of polar sensor_msgs images (both
            sonars; evenly spaced beams) where a sonar has no preset or table of its own.
        horizontal_sonar, vertical_sonar: the sonar's geometry: a preset name
            (`configs/sonars/`, e.g. "oculus-m750d-750khz", "aris3000-128") or a CSV/YAML
            file of beam angles [deg] in image-column order, positive to the sonar's left.
            Gives polar images their (possibly uneven) beam table, and every sonar its
            fan, range and vertical aperture in `sensors.json` (None: from the messages).
        horizontal_image_max_range_m, vertical_image_max_range_m: range of that sonar's
            polar images [m] (None: image_max_range_m).
        message_definitions: `.msg` / `.idl` files of custom ROS 2 message types the
            recording uses (a .msg file's type is its path: pkg/msg/Name.msg).
        base_frame: the vehicle frame mounts are composed from in the recording's tf tree.
        *_mount_xyz_m, *_mount_rpy_deg: T_base_sensor; None takes it from the recording's
            /tf_static (/tf) tree by the sensor messages' frame_id, else a default (warned).
            Set, they override the recording.
        submap_stride: dense submaps (stage `submaps`): every keyframe also maps every
            k-th ping pair recorded between it and the next keyframe; 0 maps keyframes
            only (the paper). Read by `submaps` only, so it is not in this stage's key.
    """

    spacing_m: float = Field(2.0, gt=0.0, le=1000.0)
    rotation_deg: float = Field(30.0, gt=0.0, le=360.0)
    min_gap_s: float = Field(1.0, ge=0.0, le=3600.0)
    pair_tolerance_s: float = Field(0.1, ge=0.0, le=60.0)
    horizontal_topic: str | None = Field(None, min_length=1)
    vertical_topic: str | None = Field(None, min_length=1)
    navigation_topic: str | None = Field(None, min_length=1)
    ground_truth_topic: str | None = Field(None, min_length=1)
    dvl_topic: str | None = Field(None, min_length=1)
    imu_topic: str | None = Field(None, min_length=1)
    depth_topic: str | None = Field(None, min_length=1)
    dvl_max_velocity_mps: float = Field(5.0, gt=0.0, le=50.0)
    water_density_kg_m3: float = Field(1025.0, ge=900.0, le=1100.0)
    gravity_m_s2: float = Field(9.80665, ge=9.7, le=9.9)
    surface_pressure_pa: float | None = Field(None, ge=50_000.0, le=120_000.0)
    surface_pressure_from_first_s: float | None = Field(None, gt=0.0, le=3600.0)
    image_fov_deg: float = Field(130.0, gt=0.0, le=360.0)
    image_max_range_m: float = Field(30.0, gt=0.0, le=1000.0)
    horizontal_sonar: str | None = Field(None, min_length=1, max_length=4096)
    vertical_sonar: str | None = Field(None, min_length=1, max_length=4096)
    horizontal_image_max_range_m: float | None = Field(None, gt=0.0, le=1000.0)
    vertical_image_max_range_m: float | None = Field(None, gt=0.0, le=1000.0)
    message_definitions: tuple[Annotated[str, Field(min_length=1, max_length=4096)], ...] = Field(
        (), max_length=64
    )
    base_frame: str = Field("base_link", min_length=1, max_length=200)
    horizontal_mount_xyz_m: tuple[_MountM, _MountM, _MountM] | None = None
    horizontal_mount_rpy_deg: tuple[_MountDeg, _MountDeg, _MountDeg] | None = None
    vertical_mount_xyz_m: tuple[_MountM, _MountM, _MountM] | None = None
    vertical_mount_rpy_deg: tuple[_MountDeg, _MountDeg, _MountDeg] | None = None
    dvl_mount_xyz_m: tuple[_MountM, _MountM, _MountM] | None = None
    dvl_mount_rpy_deg: tuple[_MountDeg, _MountDeg, _MountDeg] | None = None
    imu_mount_rpy_deg: tuple[_MountDeg, _MountDeg, _MountDeg] | None = None
    submap_stride: int = Field(0, ge=0, le=10000)


def select_keyframes(
    t_ns: np.ndarray, poses: np.ndarray, spacing_m: float, rotation_rad: float, min_gap_ns: int
) -> tuple[np.ndarray, list[str]]:
    """Keyframe selection by travel / turn since the last keyframe.

    Args:
        t_ns: (k,) int64 ascending candidate times [ns].
        poses: (k, 6) x, y, z, roll, pitch, yaw of each candidate.
        spacing_m: travel threshold [m].
        rotation_rad: |yaw change| threshold [rad].
        min_gap_ns: minimum time between keyframes [ns].

    Returns:
        (indices of the selected candidates, reason per keyframe: "first",
        "translation" or "rotation").
    """
    if len(t_ns) == 0:
        return np.zeros(0, np.int64), []
    chosen, reasons = [0], ["first"]
    last = 0
    for i in range(1, len(t_ns)):
        if t_ns[i] - t_ns[last] < min_gap_ns:
            continue
        moved = float(np.linalg.norm(poses[i, :3] - poses[last, :3]))
        dyaw = float(np.abs(np.angle(np.exp(1j * (poses[i, 5] - poses[last, 5])))))
        if moved >= spacing_m or dyaw >= rotation_rad:
            chosen.append(i)
            reasons.append("translation" if moved >= spacing_m else "rotation")
            last = i
    return np.asarray(chosen, np.int64), reasons


def _table(
    t_h: np.ndarray,
    t_v: np.ndarray,
    h_idx: np.ndarray,
    v_idx: np.ndarray,
    pose: np.ndarray,
    gt: np.ndarray | None,
    reasons: list[str],
) -> pa.Table:
    n = len(t_h)
    cols: dict[str, Any] = {
        "keyframe_id": np.arange(n, dtype=np.int64),
        "t_ns": t_h,
        "t_vertical_ns": t_v,
        "ping_index_horizontal": h_idx,
        "ping_index_vertical": v_idx,
    }
    for c, name in enumerate(POSE_COLUMNS):
        cols[name] = pose[:, c]
    for c, name in enumerate(GT_POSE_COLUMNS):
        values = None if gt is None else gt[:, c]
        cols[name] = pa.array(
            values if values is not None else [None] * n, pa.float64(), from_pandas=True
        )
    cols["reason"] = pa.array(reasons, pa.string())
    return pa.table(cols, schema=KEYFRAMES_SCHEMA)


def _frames(
    rec: Recording, t_h: np.ndarray, t_v: np.ndarray, h_idx: np.ndarray, v_idx: np.ndarray
) -> Iterator[KeyframeImages]:
    pairs = zip(rec.pings("horizontal", h_idx), rec.pings("vertical", v_idx), strict=True)
    for k, (hp, vp) in enumerate(pairs):
        yield KeyframeImages(
            int(k), int(t_h[k]), hp, vp, {"pair_dt_s": float(t_v[k] - t_h[k]) * 1e-9}
        )


def run(config: KeyframesConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    """Stage entry point: {"dataset": Recording} -> keyframes, frames, sensors, scene_mesh."""
    rec: Recording = inputs["dataset"]
    posed = posed_pairs(rec, config.pair_tolerance_s)
    h_t, v_t, pairs, pose, cand = posed.h_t_ns, posed.v_t_ns, posed.pairs, posed.pose, posed.posed
    t_pair = h_t[pairs.horizontal]
    sel, reasons = select_keyframes(
        t_pair[cand],
        pose[cand],
        config.spacing_m,
        np.deg2rad(config.rotation_deg),
        round(config.min_gap_s * 1e9),
    )
    if len(sel) == 0:
        # Bad data, not a bug: the engine reports it as exit 2 naming the recording.
        raise StageInputError(
            DATASET,
            f"no keyframe: {len(pairs.horizontal)} sonar pairs ({len(h_t)} horizontal, "
            f"{len(v_t)} vertical pings), {len(cand)} inside the navigation stream",
        )
    k = cand[sel]
    log.info(
        "%s: %d/%d horizontal pings paired (%d horizontal, %d vertical unpaired), "
        "%d pairs outside the navigation stream, %d keyframes",
        rec.name,
        len(pairs.horizontal),
        len(h_t),
        pairs.unpaired_horizontal,
        pairs.unpaired_vertical,
        len(pairs.horizontal) - len(cand),
        len(k),
    )
    h_idx, v_idx = pairs.horizontal[k], pairs.vertical[k]
    t_h, t_v = h_t[h_idx], v_t[v_idx]
    truth = rec.ground_truth()
    gt = None
    if truth is not None:
        gt, _ = interpolate_poses(truth, t_h)
    mounts = rec.mountings()
    sensors: dict[str, Any] = {
        s: {"T_base_sonar": np.asarray(mounts[s], np.float64).round(12).tolist()}
        for s in ("horizontal", "vertical")
    }
    # Where each role's topic, frame and mount came from (recording, config or default).
    provenance = getattr(rec, "provenance", None)
    described = rec.describe()
    for s, idx in (("horizontal", h_idx), ("vertical", v_idx)):
        ping = next(iter(rec.pings(s, idx[:1], labels=False)))  # the first keyframe's
        sensors[s].update(sonar_geometry(ping, (described.get("sonars") or {}).get(s)))
    sensors.update(
        provenance=provenance() if callable(provenance) else {},
        has_ground_truth=truth is not None,
        has_labels=bool(rec.has_labels),
        source={
            **{k2: v for k2, v in described.items() if k2 not in ("path", "sonars")},
            "name": rec.name,
        },
        pairing={
            "horizontal_pings": len(h_t),
            "vertical_pings": len(v_t),
            "pairs": len(pairs.horizontal),
            "unpaired_horizontal": pairs.unpaired_horizontal,
            "unpaired_vertical": pairs.unpaired_vertical,
            "pairs_outside_navigation": int(len(pairs.horizontal) - len(cand)),
            "keyframes": len(k),
        },
    )
    return {
        "keyframes": _table(t_h, t_v, h_idx, v_idx, pose[k], gt, reasons),
        "frames": _frames(rec, t_h, t_v, h_idx, v_idx),
        "sensors": sensors,
        "scene_mesh": rec.attachments().get("scene.ply"),
    }


STAGE = Stage(
    name="keyframes",
    # 3: keyframes.mcap in LZ4 chunks (was zstd): same images, other bytes
    version=3,
    config=KeyframesConfig,
    inputs=(DATASET,),
    outputs=(
        Output("keyframes", "parquet", "keyframes.parquet", schema=KEYFRAMES_SCHEMA),
        Output("frames", "frames", "keyframes.mcap"),
        Output("sensors", "json", "sensors.json", record=Sensors),
        Output("scene_mesh", "bytes", "scene.ply", optional=True),
    ),
    run=run,
    description="pair sonar pings, pose them from navigation, select keyframes by spacing",
    key_excludes=("submap_stride",),
)
