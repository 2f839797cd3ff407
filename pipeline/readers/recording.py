"""`SourceRecording`: a `sonarmap.schemas.recording.Recording` over any `Source`."""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.readers.clock import check_stamp_range, gap_warning
from sonarmap.pipeline.readers.dead_reckoning import NavigationSensors
from sonarmap.pipeline.readers.geometry_checks import (
    MAX_JUMP_M,
    MAX_SPEED_MPS,
    navigation_doubts,
    navigation_glitches,
    navigation_jump,
    ned_convention,
    no_overlap,
    valid_pose_rows,
)
from sonarmap.pipeline.readers.mounts import DEFAULT_SONAR_MOUNTS, mounting_matrix
from sonarmap.pipeline.readers.navigation import nav_pose, ned_note, pose_track_rows
from sonarmap.pipeline.readers.navigation_checks import far_position, shared_times, sparse_samples
from sonarmap.pipeline.readers.roles import Roles, detect_roles
from sonarmap.pipeline.readers.sonar_decode import (
    decode_image,
    decode_sonar,
    fits_ping,
    label_column_order,
    sonar_descriptions,
)
from sonarmap.pipeline.readers.source_types import Source
from sonarmap.pipeline.readers.stamp_offsets import median_offset_s, stamp_ns
from sonarmap.pipeline.readers.tf_tree import TfConflict, TfTree
from sonarmap.schemas.recording import PoseTrack
from sonarmap.schemas.sonar import SonarPing
from sonarmap.schemas.topics import FRAME_BASE
from sonarmap.stages.kernels.geometry import matrix_from_quat, se3

__all__ = ["DEFAULT_SONAR_MOUNTS", "ReaderOptions", "SourceRecording", "mounting_matrix"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReaderOptions:
    """What the readers take from the keyframes config (same field names; defaults are
    `sonarmap.stages.keyframes.KeyframesConfig`'s).

    Defaults: topics found by type; polar-image beam table 130 deg over 30 m (the
    paper's Oculus settings); DVL samples above 5 m/s dropped as implausible; mounts
    from the recording's tf tree, else the project's default sonar mountings (docs/architecture.md
    conventions, `DEFAULT_SONAR_MOUNTS`) with a warning.
    """

    horizontal_topic: str | None
    vertical_topic: str | None
    navigation_topic: str | None
    ground_truth_topic: str | None
    dvl_topic: str | None
    imu_topic: str | None
    depth_topic: str | None
    dvl_max_velocity_mps: float
    image_fov_deg: float
    image_max_range_m: float
    horizontal_sonar: str | None
    vertical_sonar: str | None
    horizontal_image_max_range_m: float | None
    vertical_image_max_range_m: float | None
    image_bits: int | None
    message_definitions: tuple[str, ...]
    horizontal_mount_xyz_m: tuple[float, float, float] | None
    horizontal_mount_rpy_deg: tuple[float, float, float] | None
    vertical_mount_xyz_m: tuple[float, float, float] | None
    vertical_mount_rpy_deg: tuple[float, float, float] | None
    water_density_kg_m3: float = 1025.0
    gravity_m_s2: float = 9.80665
    surface_pressure_pa: float | None = None
    surface_pressure_from_first_s: float | None = None
    base_frame: str = FRAME_BASE
    dvl_mount_xyz_m: tuple[float, float, float] | None = None
    dvl_mount_rpy_deg: tuple[float, float, float] | None = None
    imu_mount_rpy_deg: tuple[float, float, float] | None = None

    @classmethod
    def from_config(cls, config: Any) -> ReaderOptions:
        """Pick the fields of the same name from a config object or mapping (others ignored)."""
        from sonarmap.stages.keyframes import KeyframesConfig

        if isinstance(config, ReaderOptions):
            return config
        defaults = KeyframesConfig()  # the defaults live once, in the stage's config model
        source = {} if config is None else config
        get = source.get if isinstance(source, dict) else lambda k, d: getattr(source, k, d)
        values: dict[str, Any] = {
            f.name: get(f.name, getattr(defaults, f.name)) for f in fields(cls)
        }
        kwargs: dict[str, Any] = {
            k: (tuple(v) if isinstance(v, list) else v) for k, v in values.items()
        }
        return cls(**kwargs)


def _floats(values: np.ndarray) -> str:
    return ", ".join(f"{v:.6g}" for v in values.tolist())


class SourceRecording(NavigationSensors):
    """The keyframes stage's view of a recording (implements `sonarmap.schemas.recording.Recording`)."""

    def __init__(self, source: Source, options: ReaderOptions, roles: Roles | None = None) -> None:
        self.source = source
        self.options = options
        self._topics = source.topics()
        self.roles = roles or detect_roles(source.path, self._topics, options)
        check_stamp_range(source.path, self._topics, self.roles.as_dict().values())
        self._types = {t.topic: t.msgtype for t in self._topics}
        self._nav: PoseTrack | None = None
        self._pose_tracks: dict[str, PoseTrack] | None = None
        self._ping_times: dict[str, np.ndarray] = {}
        self._mounts: dict[str, np.ndarray] | None = None
        self._tf: TfTree | None = None
        self._tf_dynamic = False
        self._provenance: dict[str, Any] = {}
        self._nav_offsets_ns: list[int] = []  # log time - header stamp, navigation
        self._ping_stamps: dict[tuple[str, int], int | None] = {}

    def __reduce__(self) -> tuple[Any, tuple[Path, ReaderOptions, Roles]]:
        """Pickles as its path, options and topic roles: a worker process reopens the
        file (open handles and decoded streams do not cross processes)."""
        return _reopened, (self.source.path, self.options, self.roles)

    @property
    def name(self) -> str:
        return self.source.path.name

    @property
    def has_labels(self) -> bool:
        return all(s in self.roles.labels for s in self.roles.sonar)

    @property
    def has_ground_truth(self) -> bool:
        return self.roles.ground_truth is not None

    def ping_times_ns(self, sonar: str) -> np.ndarray:
        if sonar not in self._ping_times:
            topic = self.roles.sonar[sonar]
            raw = self.source.times(topic)
            times = np.unique(raw)
            if len(raw) > 1 and len(times) == 1:
                raise SourceError(
                    f"{self.source.path}: {topic}: all {len(raw)} messages have the same "
                    f"time t_ns={int(times[0])}; the recording's timestamps are broken"
                )
            if len(times) < len(raw):
                self._warn(
                    f"{self.source.path}: {topic}: dropped {len(raw) - len(times)} of "
                    f"{len(raw)} pings (duplicate timestamps; the first of each is used)"
                )
            gap = gap_warning(
                f"{self.source.path}: {topic}",
                times,
                "pings",
                "nothing is mapped across a jump (the sonar stopped, or its clock was set on)",
            )
            if gap:
                self._warn(gap)
            self._ping_times[sonar] = times
        return self._ping_times[sonar]

    def _warn(self, message: str) -> None:
        self.source.warnings.append(message)
        log.warning(message)

    def _checked_rows(
        self, topic: str, rows: list[tuple[float, ...]], ned: tuple[bool, ...] = ()
    ) -> PoseTrack:
        """A navigation topic's rows as a PoseTrack, bad samples dropped with a warning:
        non-finite positions or orientations, zero quaternions and isolated glitches.

        Raises:
            SourceError: no sample is usable, or the track jumps as no vehicle moves.
        """
        where = f"{self.source.path}: {topic}"
        track = np.asarray(rows, np.float64).reshape(-1, 8)
        n = len(track)
        ok = valid_pose_rows(track[:, 1:4], track[:, 4:8])
        if n and not ok.any():
            raise SourceError(
                f"{where}: none of the {n} navigation samples has a finite position and "
                f"a finite, non-zero orientation quaternion (first at t_ns={int(track[0, 0])})"
            )
        if not ok.all():
            self._warn(
                f"{where}: dropped {n - int(ok.sum())} of {n} navigation samples "
                "(non-finite position or orientation, or a zero quaternion)"
            )
        if (far := far_position(where, track[ok])) is not None:
            raise SourceError(far)
        kept = [r for r, good in zip(rows, ok.tolist(), strict=True) if good]
        # The navigation's frames named NED / FRD (world, body): converted to ENU / FLU.
        out = pose_track_rows(kept, *(ned if topic == self.roles.navigation else ()))
        navigating = topic == self.roles.navigation and "horizontal" in self.roles.sonar
        pings = self.ping_times_ns("horizontal") if navigating else None
        gap = gap_warning(where, out.t_ns, "a pose", pings_ns=pings)
        if gap:
            self._warn(gap)
        for line in (shared_times(where, track[ok]), sparse_samples(where, out.t_ns)):
            if line is not None:
                self._warn(line)
        glitch = navigation_glitches(out.t_ns, out.xyz_m)
        if glitch.any():
            self._warn(
                f"{where}: dropped {int(glitch.sum())} of {len(out)} navigation samples "
                f"(isolated jumps over {MAX_JUMP_M:g} m, first at t_ns={int(out.t_ns[glitch][0])})"
            )
            out = PoseTrack(out.t_ns[~glitch], out.xyz_m[~glitch], out.rpy_rad[~glitch])
        k = navigation_jump(out.t_ns, out.xyz_m)
        if k is not None:
            dist = float(np.linalg.norm(out.xyz_m[k + 1] - out.xyz_m[k]))
            dt = float(out.t_ns[k + 1] - out.t_ns[k]) * 1e-9
            raise SourceError(
                f"{where}: the navigation jumps {dist:.4g} m in {dt:.3g} s at "
                f"t_ns={int(out.t_ns[k + 1])} (more than {MAX_SPEED_MPS:g} m/s; no vehicle "
                "moves so: fix or cut the navigation there)"
            )
        return out

    def _tracks(self) -> dict[str, PoseTrack]:
        """Navigation and ground-truth tracks, read in one pass: where they share chunks
        with the sonar images (most recorders interleave), each pass decompresses them all."""
        if self._pose_tracks is None:
            topics = sorted({t for t in (self.roles.navigation, self.roles.ground_truth) if t})
            rows: dict[str, list[tuple[float, ...]]] = {t: [] for t in topics}
            first = None
            for topic, t, m in self.source.messages(topics):
                rows[topic].append((t, *nav_pose(m)))
                first = m if first is None and topic == self.roles.navigation else first
                if topic == self.roles.navigation and (stamp := stamp_ns(m)) is not None:
                    self._nav_offsets_ns.append(t - stamp)
            if any(ned := ned_convention(first)):
                self._warn(f"{self.source.path}: {self.roles.navigation}: {ned_note(*ned)}")
            self._pose_tracks = {k: self._checked_rows(k, r, ned) for k, r in rows.items()}
        return self._pose_tracks

    def navigation(self) -> PoseTrack:
        if self._nav is None:
            if self.roles.navigation is not None:
                self._nav = self._with_depth(self._tracks()[self.roles.navigation])
                role = self._role(self.roles.navigation)
                self._provenance["navigation"] = {**role, "source": "recording"}
            elif self.roles.dvl is not None:
                self._nav = self._dead_reckoning()
            else:
                self._nav = PoseTrack(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
            self._check_overlap(self._nav)
        return self._nav

    def _check_overlap(self, nav: PoseTrack) -> None:
        """Refuse navigation that spans none of the horizontal pings: no ping can be posed."""
        topic = self.roles.sonar.get("horizontal")
        if len(nav) == 0 or topic is None:
            return
        t = self.ping_times_ns("horizontal")
        if (problem := no_overlap(t, nav.t_ns)) is not None:
            raise SourceError(f"{self.source.path}: {topic}: {problem}")
        for line in navigation_doubts(t, nav.t_ns, nav.rpy_rad):
            self._warn(f"{self.source.path}: {line}")

    def ground_truth(self) -> PoseTrack | None:
        return None if self.roles.ground_truth is None else self._tracks()[self.roles.ground_truth]

    def pings(
        self, sonar: str, indices: Sequence[int] | np.ndarray, labels: bool = True
    ) -> Iterator[SonarPing]:
        """Decode the requested pings (with their label/truth images unless `labels` is
        False), streaming."""
        idx = np.asarray(indices, np.int64)
        if len(idx) == 0:
            return
        if np.any(np.diff(idx) < 0):
            raise ValueError("ping indices must be non-decreasing")
        times = self.ping_times_ns(sonar)[idx]
        topic = self.roles.sonar[sonar]
        extra = {
            name: part
            for name, part in (
                (self.roles.labels.get(sonar), "labels"),
                (self.roles.truth_angle.get(sonar), "truth"),
            )
            if name is not None and labels
        }
        groups: dict[int, dict[str, Any]] = {}
        cursor = 0
        where = f"{self.source.path} topic {topic}"
        for name, t, msg in self.source.messages([topic, *extra], set(times.tolist())):
            while cursor < len(times) and times[cursor] < t:
                yield self._assemble(groups, int(times[cursor]), sonar, where)
                cursor += 1
            groups = {k: v for k, v in groups.items() if k >= t}
            groups.setdefault(t, {})["ping" if name == topic else extra[name]] = msg
        for k in range(cursor, len(times)):
            yield self._assemble(groups, int(times[k]), sonar, where)

    def _assemble(
        self, groups: dict[int, dict[str, Any]], t: int, sonar: str, where: str
    ) -> SonarPing:
        parts = groups.get(t, {})
        if "ping" not in parts:
            raise SourceError(f"{where}: the ping at t_ns={t} could not be read")
        msgtype = self._types[self.roles.sonar[sonar]]
        ping = decode_sonar(parts["ping"], msgtype, t, sonar, self.options, where)
        self._ping_stamps[(sonar, t)] = stamp_ns(parts["ping"])
        if "labels" not in parts and "truth" not in parts:
            return ping
        order = label_column_order(parts["ping"], msgtype, sonar, self.options, ping.image.shape[1])
        labels = truth = None
        try:
            if "labels" in parts:
                image = decode_image(parts["labels"]).astype(np.uint8)
                labels = np.ascontiguousarray(fits_ping(image, ping.image)[:, order])
            if "truth" in parts:
                image = decode_image(parts["truth"]).astype(np.float32)
                truth = np.ascontiguousarray(fits_ping(image, ping.image)[:, order])
        except (ValueError, OSError, IndexError) as err:
            raise SourceError(f"{where}: bad label or truth image at t_ns={t} ({err})") from err
        return replace(ping, labels=labels, truth_angle_rad=truth)

    def stamp_offset_s(self, sonar: str, t_ns: int) -> float | None:
        """Log time - header stamp [s] of a ping decoded by `pings` (None: no stamp)."""
        stamp = self._ping_stamps.get((sonar, t_ns))
        return None if stamp is None else (t_ns - stamp) * 1e-9

    def tf_tree(self, dynamic: bool = False) -> TfTree:
        """The recording's /tf_static tree; with `dynamic`, /tf's edges too (the first
        value of each: a mount on /tf is expected not to change)."""
        if self._tf is None:
            self._tf = self._read_tf(TfTree(), self.roles.tf_static)
        if dynamic and not self._tf_dynamic:
            self._tf_dynamic = True
            self._read_tf(self._tf, self.roles.tf)
        return self._tf

    def _read_tf(self, tree: TfTree, topic: str | None) -> TfTree:
        if topic is None:
            return tree
        for _, _, msg in self.source.messages([topic]):
            for tf in msg.transforms:
                try:
                    tree.add(tf.header.frame_id, tf.child_frame_id, self._mounting(tf, topic))
                except TfConflict as err:
                    raise SourceError(f"{self.source.path}: {topic}: {err}") from None
        return tree

    def _mounting(self, tf: Any, topic: str) -> np.ndarray:
        """(4, 4) T_parent_child of a /tf or /tf_static transform; a rotation quaternion of
        zero or non-finite norm, or a non-finite translation, is refused (it would place
        every point of a sensor below it nowhere)."""
        q, tr = tf.transform.rotation, tf.transform.translation
        xyz = np.array([tr.x, tr.y, tr.z], np.float64)
        where = f"{self.source.path}: {topic}: transform {tf.header.frame_id.lstrip('/')} -> "
        where += tf.child_frame_id.lstrip("/")
        if not np.all(np.isfinite(xyz)):
            raise SourceError(f"{where}: translation is not finite ({_floats(xyz)})")
        try:
            return se3(matrix_from_quat([q.x, q.y, q.z, q.w]), xyz)
        except ValueError:
            quat = np.array([q.x, q.y, q.z, q.w], np.float64)
            raise SourceError(
                f"{where}: rotation quaternion (x, y, z, w) = ({_floats(quat)}) has zero "
                "or non-finite norm"
            ) from None

    def attachments(self) -> dict[str, bytes]:
        return self.source.attachments()

    def describe(self) -> dict[str, object]:
        return {
            "path": str(self.source.path),
            "format": self.source.kind,
            "topics": self.roles.as_dict(),
            "sonars": sonar_descriptions(self.options, self.roles.sonar, self._types, self.source),
            "warnings": list(self.source.warnings),
            "navigation_stamp_offset_s": median_offset_s(self._nav_offsets_ns),
        }


def _reopened(path: Path, options: ReaderOptions, roles: Roles) -> SourceRecording:
    from sonarmap.pipeline.readers.sources import open_source

    return SourceRecording(open_source(path, options.message_definitions), options, roles)
