"""The `frames` artifact codec: keyframe sonar images <-> a ROS 2 MCAP.

Per keyframe, `keyframes.mcap` holds one `marine_acoustic_msgs/msg/ProjectedSonarImage`
per sonar (/sonar/horizontal, /sonar/vertical; header stamp = that ping's time) and,
when present, the label (mono8) and truth-angle (32FC1) images on the topics of
`sonarmap.schemas.topics`. Every message of keyframe k is logged at the keyframe's time t_ns
(unique per keyframe); a metadata record "sonarmap.keyframes" maps keyframe ids to
times and extras. Opens in Foxglove; reading back is lazy, by index. Its chunks are
LZ4-compressed: fast to write and read (docs/decisions/ has the measurement).
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, overload

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType

from sonarmap.pipeline.engine.errors import ArtifactCorrupt
from sonarmap.pipeline.formats.projected_cdr import ProjectedArrays, serialize_projected_cdr
from sonarmap.pipeline.formats.rosmsg import Ros2McapWriter, ros2_typestore
from sonarmap.schemas.sonar import (
    KeyframeImages,
    SonarPing,
    beam_angles_from_directions,
    beam_directions_from_angles,
)
from sonarmap.schemas.topics import (
    FRAME_SONAR,
    IMAGE_TYPE,
    LABEL_TOPIC,
    PROJECTED_SONAR_TYPE,
    SONAR_TOPIC,
    SONARS,
    TRUTH_ANGLE_TOPIC,
)

__all__ = [
    "FramesSequence",
    "image_message",
    "read_frames",
    "sonar_cdr",
    "sonar_message",
    "write_frames",
]

_META = "sonarmap.keyframes"


def _stamp(t_ns: int) -> Any:
    Time = ros2_typestore().types["builtin_interfaces/msg/Time"]
    return Time(sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000))


def _header(t_ns: int, frame: str) -> Any:
    return ros2_typestore().types["std_msgs/msg/Header"](stamp=_stamp(t_ns), frame_id=frame)


def sonar_message(ping: SonarPing, frame_id: str) -> Any:
    """SonarPing -> ProjectedSonarImage (range-major uint8 image, unit beam vectors)."""
    types = ros2_typestore().types
    Vector3 = types["geometry_msgs/msg/Vector3"]
    dirs = beam_directions_from_angles(np.asarray(ping.angles_rad, np.float64))
    return types[PROJECTED_SONAR_TYPE](
        header=_header(ping.t_ns, frame_id),
        ping_info=types["marine_acoustic_msgs/msg/PingInfo"](
            frequency=float(ping.frequency_hz),
            sound_speed=float(ping.sound_speed_m_s),
            tx_beamwidths=np.zeros(0, np.float32),
            rx_beamwidths=np.zeros(0, np.float32),
        ),
        beam_directions=[Vector3(x=float(d[0]), y=float(d[1]), z=float(d[2])) for d in dirs],
        ranges=np.asarray(ping.ranges_m, np.float32),
        image=types["marine_acoustic_msgs/msg/SonarImageData"](
            is_bigendian=False,
            dtype=0,
            beam_count=int(ping.image.shape[1]),
            data=np.ascontiguousarray(ping.image, np.uint8).reshape(-1),
        ),
    )


def sonar_cdr(ping: SonarPing, frame_id: str) -> bytes:
    """SonarPing -> CDR bytes of the ProjectedSonarImage `sonar_message` would give (fast path)."""
    dirs = beam_directions_from_angles(np.asarray(ping.angles_rad, np.float64))
    return serialize_projected_cdr(
        ping.t_ns, frame_id, dirs, ping.ranges_m, ping.image,
        (ping.frequency_hz, ping.sound_speed_m_s),
    )  # fmt: skip


def image_message(array: np.ndarray, t_ns: int, frame_id: str) -> Any:
    """(h, w) uint8 -> mono8 or float32 -> 32FC1 sensor_msgs/Image."""
    a = np.ascontiguousarray(array)
    encoding = "mono8" if a.dtype == np.uint8 else "32FC1"
    a = a if a.dtype == np.uint8 else a.astype("<f4")
    return ros2_typestore().types[IMAGE_TYPE](
        header=_header(t_ns, frame_id),
        height=a.shape[0],
        width=a.shape[1],
        encoding=encoding,
        is_bigendian=0,
        step=a.shape[1] * a.itemsize,
        data=a.view(np.uint8).reshape(-1),
    )


def write_frames(frames: Iterable[KeyframeImages], path: Path) -> int:
    """Write keyframe images to a ROS 2 MCAP, streaming; returns the number of keyframes.

    Deterministic: the same frames give the same bytes. Keyframe times must be unique
    and ascending (they are the log times).
    """
    index: list[list[Any]] = []
    last_t = -1
    # LZ4, not zstd: zstd over the images cost about 1 s of a 4 s stage. Uncompressed
    # would be ~11x the bytes (650 MB for the marina), each hashed at commit and on reads.
    with Path(path).open("wb") as f, Ros2McapWriter(f, compression=CompressionType.LZ4) as w:
        for kf in frames:
            if kf.t_ns <= last_t:
                raise ValueError(f"keyframe {kf.keyframe_id}: t_ns {kf.t_ns} not after {last_t}")
            last_t = kf.t_ns
            for sonar, ping in ((s, getattr(kf, s)) for s in SONARS):
                frame = FRAME_SONAR[sonar]
                w.write_raw(
                    SONAR_TOPIC[sonar], PROJECTED_SONAR_TYPE, sonar_cdr(ping, frame), kf.t_ns
                )
                if ping.labels is not None:
                    w.write(
                        LABEL_TOPIC[sonar],
                        IMAGE_TYPE,
                        image_message(ping.labels.astype(np.uint8), ping.t_ns, frame),
                        kf.t_ns,
                    )
                if ping.truth_angle_rad is not None:
                    msg = image_message(ping.truth_angle_rad.astype(np.float32), ping.t_ns, frame)
                    w.write(TRUTH_ANGLE_TOPIC[sonar], IMAGE_TYPE, msg, kf.t_ns)
            index.append(
                [
                    int(kf.keyframe_id),
                    int(kf.t_ns),
                    {k: float(v) for k, v in sorted(kf.extras.items())},
                ]
            )
        w.add_metadata(
            _META, {"count": str(len(index)), "index": json.dumps(index, sort_keys=True)}
        )
    return len(index)


def _ping(msg: ProjectedArrays, sonar: str) -> SonarPing:
    ranges = np.array(msg.ranges, np.float32)
    image = msg.data.reshape(len(ranges), len(msg.directions)).copy()
    angles = beam_angles_from_directions(msg.directions).astype(np.float32)
    return SonarPing(
        msg.stamp_ns, sonar, image, ranges, angles,
        frequency_hz=msg.frequency_hz, sound_speed_m_s=msg.sound_speed_m_s,
    )  # fmt: skip


def _image(msg: Any) -> np.ndarray:
    dtype = np.uint8 if msg.encoding == "mono8" else np.dtype("<f4")
    return np.frombuffer(bytes(msg.data), dtype).reshape(msg.height, msg.width)


class FramesSequence(Sequence[KeyframeImages]):
    """Lazy read-only sequence over `keyframes.mcap`; item i decodes keyframe i only."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        with self.path.open("rb") as f:
            reader = make_reader(f)
            meta = [m for m in reader.iter_metadata() if m.name == _META]
        if not meta:
            raise ArtifactCorrupt(f"{self.path}: no '{_META}' metadata record")
        self._index = json.loads(meta[0].metadata["index"])
        self._store = ros2_typestore()
        self._topics = {SONAR_TOPIC[s]: (s, "ping") for s in SONARS}
        self._topics.update({LABEL_TOPIC[s]: (s, "labels") for s in SONARS})
        self._topics.update({TRUTH_ANGLE_TOPIC[s]: (s, "truth") for s in SONARS})

    def __len__(self) -> int:
        return len(self._index)

    def _build(self, i: int, parts: dict[tuple[str, str], Any]) -> KeyframeImages:
        kid, t, extras = self._index[i]
        pings = {}
        for s in SONARS:
            if (s, "ping") not in parts:
                raise ArtifactCorrupt(f"{self.path}: keyframe {kid} lacks its {s} sonar image")
            p = _ping(parts[(s, "ping")], s)
            labels = _image(parts[(s, "labels")]) if (s, "labels") in parts else None
            truth = _image(parts[(s, "truth")]) if (s, "truth") in parts else None
            pings[s] = replace(p, labels=labels, truth_angle_rad=truth)
        return KeyframeImages(
            int(kid), int(t), pings["horizontal"], pings["vertical"], dict(extras)
        )

    def _messages(self, reader: Any, **kw: Any) -> Iterator[tuple[int, tuple[str, str], Any]]:
        for schema, channel, message in reader.iter_messages(topics=list(self._topics), **kw):
            key = self._topics[channel.topic]
            if key[1] == "ping":
                yield message.log_time, key, ProjectedArrays.from_cdr(message.data)
            else:
                yield message.log_time, key, self._store.deserialize_cdr(message.data, schema.name)

    @overload
    def __getitem__(self, i: int) -> KeyframeImages: ...
    @overload
    def __getitem__(self, i: slice) -> list[KeyframeImages]: ...
    def __getitem__(self, i: int | slice) -> KeyframeImages | list[KeyframeImages]:
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError(i)
        t = self._index[i][1]
        with self.path.open("rb") as f:
            parts = {
                key: msg
                for _, key, msg in self._messages(
                    make_reader(f), starting_at=t, ending_before=t + 1
                )
            }
        return self._build(i, parts)

    def __iter__(self) -> Iterator[KeyframeImages]:
        """One sequential pass over the file (faster than indexing one by one)."""
        pos = {entry[1]: k for k, entry in enumerate(self._index)}
        with self.path.open("rb") as f:
            current, parts = None, {}
            for t, key, msg in self._messages(make_reader(f)):
                if t != current and current is not None:
                    yield self._build(pos[current], parts)
                    parts = {}
                current = t
                parts[key] = msg
            if current is not None:
                yield self._build(pos[current], parts)


def read_frames(path: Path) -> Sequence[KeyframeImages]:
    """Open `keyframes.mcap` as a lazy sequence of KeyframeImages."""
    return FramesSequence(path)
