"""ROS message types and a fast, deterministic ROS 2 MCAP writer.

Serialisation uses rosbags' CDR serde (numpy arrays in and out) around the raw
`mcap` writer, the fast path measured in docs/architecture.md (Facts that shape the code). Every
message gets explicit log/publish times so the same inputs give the same bytes.
"""

from __future__ import annotations

import functools
from importlib import resources
from types import TracebackType
from typing import IO, Any

from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

__all__ = [
    "RECORDING_CHUNK_BYTES",
    "SMALL_MESSAGE_BYTES",
    "Ros2McapWriter",
    "custom_msg_texts",
    "msgdef",
    "recording_writer",
    "ros1_typestore",
    "ros2_typestore",
]

# The layout of recordings sonarmap writes (`recording_writer`): messages up to
# SMALL_MESSAGE_BYTES (navigation, tf; a sonar image is hundreds of kB) in chunks apart
# from the images, and image chunks closed once past RECORDING_CHUNK_BYTES: one sonar
# ping with its label image, or one truth-angle image (the simulator's 512 x 600 pings),
# so a reader decompresses the navigation and the keyframes' images and little else,
# without a chunk index per image (the summary and message indexes are parsed in Python).
# The gathered small messages are also written out every SMALL_FLUSH_NS of log time, so
# a copy cut anywhere keeps the navigation up to a few seconds before the cut (gathered
# to the end, a cut copy would lose all of it, and with it every keyframe).
SMALL_MESSAGE_BYTES = 64 * 1024
RECORDING_CHUNK_BYTES = 512 * 1024
SMALL_FLUSH_NS = 5_000_000_000


def custom_msg_texts() -> dict[str, str]:
    """The .msg texts shipped in `schemas/msg`, keyed by type name ("pkg/msg/Type")."""
    root = resources.files("sonarmap.schemas") / "msg"
    texts: dict[str, str] = {}
    for pkg in sorted((p for p in root.iterdir() if p.is_dir()), key=lambda p: p.name):
        for msg in sorted((pkg / "msg").iterdir(), key=lambda p: p.name):
            if msg.name.endswith(".msg"):
                texts[f"{pkg.name}/msg/{msg.name[:-4]}"] = msg.read_text()
    return texts


def _register_custom(store: Typestore) -> Typestore:
    types: dict[str, Any] = {}
    for name, text in custom_msg_texts().items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


@functools.cache
def ros2_typestore() -> Typestore:
    """ROS 2 Humble types plus marine_acoustic_msgs and sonar_oculus."""
    return _register_custom(get_typestore(Stores.ROS2_HUMBLE))


@functools.cache
def ros1_typestore() -> Typestore:
    """ROS 1 Noetic types plus marine_acoustic_msgs and sonar_oculus."""
    return _register_custom(get_typestore(Stores.ROS1_NOETIC))


@functools.cache
def msgdef(typename: str) -> str:
    """The concatenated ROS 2 message definition MCAP stores as the schema."""
    text, _ = ros2_typestore().generate_msgdef(typename, ros_version=2)
    return text


class Ros2McapWriter:
    """Write ROS 2 (CDR) messages into one MCAP file with zstd chunks.

    Usage:
        with Ros2McapWriter(stream, metadata={"sonarmap": {...}}) as w:
            w.write("/topic", "nav_msgs/msg/Odometry", msg_object, t_ns)

    Messages are rosbags message objects (see `ros2_typestore().types`).

    With `small_message_bytes`, messages of at most that size (navigation, ground truth,
    tf) are gathered into chunks of their own instead of between the sonar images: a
    reader then gets the whole navigation stream without decompressing any image (the
    chunks overlap in time, which MCAP allows; readers order by the message indexes).
    With `small_flush_ns`, those chunks are also written once they span that much log
    time, so a copy cut short keeps the small messages written before the cut.
    `compression`: of the chunks (zstd; the keyframe images are written with LZ4,
    `sonarmap.pipeline.formats.frames_io`).
    """

    def __init__(
        self,
        stream: IO[bytes],
        *,
        chunk_size: int = 4 * 1024 * 1024,
        small_message_bytes: int | None = None,
        small_flush_ns: int | None = None,
        compression: CompressionType = CompressionType.ZSTD,
    ) -> None:
        self._writer = McapWriter(stream, chunk_size=chunk_size, compression=compression)
        self._writer.start(profile="ros2", library="sonarmap")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence = 0
        self._store = ros2_typestore()
        self._chunk_size = chunk_size
        self._small_bytes = small_message_bytes
        self._small: list[tuple[int, int, bytes, int]] = []
        self._small_size = 0
        self._small_flush_ns = small_flush_ns

    def _channel(self, topic: str, typename: str) -> int:
        if topic in self._channels:
            return self._channels[topic]
        if typename not in self._schemas:
            self._schemas[typename] = self._writer.register_schema(
                name=typename, encoding="ros2msg", data=msgdef(typename).encode()
            )
        cid = self._writer.register_channel(
            topic=topic, message_encoding="cdr", schema_id=self._schemas[typename]
        )
        self._channels[topic] = cid
        return cid

    def write(self, topic: str, typename: str, message: object, t_ns: int) -> None:
        """Serialise `message` and append it with log and publish time `t_ns`."""
        data = self._store.serialize_cdr(message, typename)
        self.write_raw(topic, typename, bytes(data), t_ns)

    def write_raw(self, topic: str, typename: str, cdr: bytes, t_ns: int) -> None:
        """Append an already CDR-serialised message."""
        cid = self._channel(topic, typename)
        if self._small_bytes is not None and len(cdr) <= self._small_bytes:
            self._small.append((cid, t_ns, cdr, self._sequence))
            self._small_size += len(cdr)
            span = self._small_flush_ns
            if self._small_size >= self._chunk_size or (
                span is not None and t_ns - self._small[0][1] >= span
            ):
                self._flush_small()
        else:
            self._writer.add_message(
                channel_id=cid, log_time=t_ns, publish_time=t_ns, sequence=self._sequence, data=cdr
            )
        self._sequence += 1

    def _flush_small(self) -> None:
        """Close the image chunk in progress, then write the gathered small messages as
        a chunk of their own."""
        if not self._small:
            return
        self._writer.flush()
        for cid, t_ns, cdr, seq in self._small:
            self._writer.add_message(
                channel_id=cid, log_time=t_ns, publish_time=t_ns, sequence=seq, data=cdr
            )
        self._writer.flush()
        self._small, self._small_size = [], 0

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record (string -> string map), e.g. provenance."""
        self._writer.add_metadata(name=name, data=data)

    def add_attachment(self, name: str, data: bytes, media_type: str, t_ns: int = 0) -> None:
        """An attachment (e.g. the ground-truth scene mesh as PLY)."""
        self._writer.add_attachment(
            create_time=t_ns, log_time=t_ns, name=name, media_type=media_type, data=data
        )

    def finish(self) -> None:
        self._flush_small()
        self._writer.finish()

    def __enter__(self) -> Ros2McapWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.finish()


def recording_writer(stream: IO[bytes]) -> Ros2McapWriter:
    """A writer with the layout of the recordings sonarmap writes (simulator, `convert`):
    navigation in chunks of its own (one per SMALL_FLUSH_NS of log time at most), images
    in chunks of one or two images."""
    return Ros2McapWriter(
        stream,
        chunk_size=RECORDING_CHUNK_BYTES,
        small_message_bytes=SMALL_MESSAGE_BYTES,
        small_flush_ns=SMALL_FLUSH_NS,
    )
