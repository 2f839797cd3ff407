"""`follow`'s preview: each keyframe mapped as soon as it is complete, between (and while)
the full updates.

A full update (`follow.Follower`) reruns the pipeline on the recording so far, which
takes seconds to tens of seconds. Meanwhile, at every poll, the preview:

1. cuts the recording's last seconds, from just before its last keyframe, out of its own
   snapshot (`window.RecordWindow`: only the new records are read);
2. pairs and poses the pings there and continues the keyframe rule from the last
   keyframe (`stages.keyframes.stage.continue_selection`: the same keyframes as a batch run);
   a pair within `pair_tolerance_s` of the newest ping waits (its partner may come);
3. detects each new keyframe's features with the last full update's calibration and
   fuses its two sonars (`kernels.preview.keyframe_points`: the batch kernels);
4. poses it by the navigation's motion since the last full update's newest keyframe,
   chained onto that keyframe's SLAM pose (dead reckoning since the update), and
   publishes every preview point so far on `/map/preview` and the preview keyframes on
   `/trajectory/preview`.

It waits for the first full update (its calibration, mounts and SLAM pose); each full
update then becomes the new anchor and the preview restarts from its newest keyframe
(the update's map holds the ones before).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sonarmap.pipeline.live.growing import Growth, McapSnapshot
from sonarmap.pipeline.live.window import RecordWindow

__all__ = ["Anchor", "Preview", "PreviewKeyframe", "unsaid"]

_MARGIN_NS = 2_000_000_000
"""The window starts this long before the last keyframe: the navigation samples around
it and the vertical ping paired with it are in the window."""
_POSE = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")


class _AboutFile(logging.Filter):
    def __init__(self, path: Path) -> None:
        super().__init__()
        self.path = str(path)

    def filter(self, record: logging.LogRecord) -> bool:
        return self.path not in record.getMessage()


@contextmanager
def unsaid(private: Path) -> Iterator[None]:
    """What is logged naming `private` is not printed: the preview's window (cut from the
    recording on purpose, so what is missing at its edges is no news) and the full
    updates' snapshot are private files, gone soon; the final run reads the recording
    itself and says what is wrong with it."""
    quiet = _AboutFile(private)
    handlers = list(logging.getLogger().handlers)
    for handler in handlers:
        handler.addFilter(quiet)
    try:
        yield
    finally:
        for handler in handlers:
            handler.removeFilter(quiet)


@dataclass(frozen=True)
class Anchor:
    """What a full update gives the preview.

    Attributes:
        keyframe_id, t_ns: its newest keyframe.
        nav_pose: (6,) that keyframe's navigation pose (keyframes.parquet).
        T_world: (4, 4) its SLAM pose (the navigation pose without a slam stage).
        thresholds: per sonar, the calibration of its features stage.
        T_base_h, T_h_v: the horizontal sonar's mount, the vertical sonar in its frame.
    """

    keyframe_id: int
    t_ns: int
    nav_pose: np.ndarray
    T_world: np.ndarray
    thresholds: dict[str, Any]
    T_base_h: np.ndarray
    T_h_v: np.ndarray


@dataclass
class PreviewKeyframe:
    """One previewed keyframe: id, time, world pose (6,) x, y, z, roll, pitch, yaw
    [m, rad], its fused points (n, 3) in the horizontal sonar frame [m] and its
    navigation pose (6,)."""

    keyframe_id: int
    t_ns: int
    pose: np.ndarray
    xyz: np.ndarray
    nav_pose: np.ndarray


@dataclass
class Preview:
    """The preview's state (see the module docstring).

    Args:
        snapshot: its own snapshot of the recording (updated at every poll).
        config: the run's config (sections keyframes, features, fuse).
        window_path: where the window file is written.
    """

    snapshot: McapSnapshot
    config: Any
    window_path: Path
    anchor: Anchor | None = None
    keyframes: list[PreviewKeyframe] = field(default_factory=list)
    growth: Growth = field(default_factory=lambda: Growth(0, 0, None, False))
    _last: tuple[int, np.ndarray] | None = None  # last keyframe: t_ns, navigation pose
    _fresh: bool = False  # a new anchor: map what is already there

    def __post_init__(self) -> None:
        self.window = RecordWindow(self.snapshot.path)

    def set_anchor(self, anchor: Anchor) -> None:
        """A full update finished: its map supersedes the preview up to its newest
        keyframe. The keyframes previewed after that one stay, posed again from the new
        anchor (their points were detected with the previous calibration: detecting them
        again would delay the new ones)."""
        from sonarmap.stages.kernels.geometry import pose_from_se3
        from sonarmap.stages.kernels.preview import chained_poses

        self.anchor = anchor
        kept = [k for k in self.keyframes if k.t_ns > anchor.t_ns]
        if kept:
            nav = np.stack([k.nav_pose for k in kept])
            T = chained_poses(anchor.T_world, anchor.nav_pose, nav)
            for i, k in enumerate(kept):
                k.keyframe_id, k.pose = anchor.keyframe_id + 1 + i, pose_from_se3(T[i])
        self.keyframes = kept
        self._last = (kept[-1].t_ns, kept[-1].nav_pose) if kept else (anchor.t_ns, anchor.nav_pose)
        self._fresh = True

    def poll(self) -> list[PreviewKeyframe]:
        """Read what arrived; the keyframes newly complete, mapped (none before an anchor)."""
        from sonarmap.pipeline.readers import open_recording
        from sonarmap.schemas.sonar import KeyframeImages
        from sonarmap.stages.kernels.geometry import pose_from_se3
        from sonarmap.stages.kernels.pairing import posed_pairs
        from sonarmap.stages.kernels.preview import chained_poses, keyframe_points
        from sonarmap.stages.keyframes.stage import continue_selection

        self.growth = growth = self.snapshot.update()
        self.window.update(self.snapshot.size)
        if self.anchor is None or self._last is None or not (growth.new_bytes or self._fresh):
            return []
        anchor, (last_t, last_pose) = self.anchor, self._last
        kcfg = self.config.keyframes
        newest = self.snapshot.last_log_time_ns
        if newest is not None and newest - last_t < round(kcfg.min_gap_s * 1e9):
            return []  # no keyframe can be due yet: the window is not even read
        self._fresh = False
        self.window.write(last_t - _MARGIN_NS, self.window_path)
        with unsaid(self.window_path):
            rec = open_recording(self.window_path, kcfg)
            posed = posed_pairs(rec, kcfg.pair_tolerance_s)
            if len(posed.h_t_ns) == 0 or len(posed.v_t_ns) == 0:
                return []
            t_pair = posed.h_t_ns[posed.pairs.horizontal]
            horizon = min(posed.h_t_ns[-1], posed.v_t_ns[-1]) - round(kcfg.pair_tolerance_s * 1e9)
            cand = posed.posed[(t_pair[posed.posed] > last_t) & (t_pair[posed.posed] <= horizon)]
            new, _ = continue_selection(
                last_t, last_pose, t_pair[cand], posed.pose[cand], kcfg.spacing_m,
                np.deg2rad(kcfg.rotation_deg), round(kcfg.min_gap_s * 1e9),
            )  # fmt: skip
            if len(new) == 0:
                return []
            k = cand[new]
            h_idx, v_idx = posed.pairs.horizontal[k], posed.pairs.vertical[k]
            T_world = chained_poses(anchor.T_world, anchor.nav_pose, posed.pose[k])
            first_id = anchor.keyframe_id + 1 + len(self.keyframes)
            pings = zip(rec.pings("horizontal", h_idx), rec.pings("vertical", v_idx), strict=True)
            out = []
            for i, (hp, vp) in enumerate(pings):
                frame = KeyframeImages(first_id + i, int(hp.t_ns), hp, vp, {})
                fu = keyframe_points(
                    frame, self.config.features, anchor.thresholds, anchor.T_h_v, self.config.fuse
                )
                xyz = np.stack([fu["x_m"], fu["y_m"], fu["z_m"]], axis=1)
                pose = pose_from_se3(T_world[i])
                out.append(
                    PreviewKeyframe(frame.keyframe_id, frame.t_ns, pose, xyz, posed.pose[k[i]])
                )
            self.keyframes.extend(out)
            self._last = (int(t_pair[k[-1]]), posed.pose[k[-1]])
            return out

    def messages(self, t_ns: int) -> list[Any]:
        """The preview so far as live-view messages (none yet: messages clearing it)."""
        import pyarrow as pa

        from sonarmap.stages.evaluate.foxglove_scene import preview_messages

        kfs = self.keyframes
        poses = np.array([k.pose for k in kfs], np.float64).reshape(-1, 6)
        table = pa.table(
            {
                "keyframe_id": pa.array([k.keyframe_id for k in kfs], pa.int64()),
                "t_ns": pa.array([k.t_ns for k in kfs], pa.int64()),
                **{c: poses[:, i] for i, c in enumerate(_POSE)},
            }
        )
        xyz = np.concatenate([k.xyz for k in kfs]) if kfs else np.zeros((0, 3))
        fused = pa.table(
            {
                "keyframe_id": np.repeat(
                    [k.keyframe_id for k in kfs], [len(k.xyz) for k in kfs]
                ).astype(np.int64),
                **{c: xyz[:, i] for i, c in enumerate(("x_m", "y_m", "z_m"))},
            }
        )
        T_base_h = np.eye(4) if self.anchor is None else self.anchor.T_base_h
        return preview_messages(fused, table, T_base_h, t_ns)


def anchor_of(result: Any, stages: dict[str, Any]) -> Anchor | None:
    """The anchor a full update's result gives (None: it made no keyframes or features)."""
    from sonarmap.pipeline.engine.store.codecs import read_output
    from sonarmap.schemas.sensors import Sensors
    from sonarmap.stages.kernels.front_end import thresholds
    from sonarmap.stages.kernels.poses import pose_matrix

    def read(stage: str, output: str) -> Any:
        ref = result.artifacts.get(stage)
        if ref is None or stage not in stages:
            return None
        spec = next(o for o in stages[stage].outputs if o.name == output)
        return read_output(Path(ref.path), spec)

    keyframes = read("keyframes", "keyframes")
    calibration = read("features", "calibration")
    if keyframes is None or keyframes.num_rows == 0 or calibration is None:
        return None
    last = keyframes.slice(keyframes.num_rows - 1)
    kf_id = int(last.column("keyframe_id")[0].as_py())
    nav = np.array([last.column(c)[0].as_py() for c in _POSE], np.float64)
    T_world = pose_matrix(nav)[0]
    poses = read("slam", "poses")
    if poses is not None:
        row = poses.filter(poses.column("keyframe_id").to_numpy() == kf_id)
        if row.num_rows:
            T_world = pose_matrix(np.array([row.column(c)[0].as_py() for c in _POSE]))[0]
    sensors = Sensors.of(read("keyframes", "sensors") or {})
    return Anchor(
        kf_id,
        int(last.column("t_ns")[0].as_py()),
        nav,
        T_world,
        thresholds(dict(calibration)),
        sensors.horizontal.T_base_sonar,
        sensors.T_h_v,
    )
