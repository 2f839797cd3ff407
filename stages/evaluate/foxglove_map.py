"""evaluate's `map.mcap`: the `sonarmap.stages.evaluate.foxglove_scene` messages of a run, written
with foxglove-sdk's MCAP writer into bytes (protobuf Foxglove schemas, zstd chunks)."""

from __future__ import annotations

import heapq
import io
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.schemas.sensors import Sensors
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.evaluate.foxglove_images import fan_messages
from sonarmap.stages.evaluate.foxglove_scene import (
    FRAME_MAP,
    TOPIC_SCHEMAS,
    SceneMessage,
    map_messages,
    mesh_messages,
    object_messages,
    trajectory_messages,
)
from sonarmap.stages.kernels.ply import Mesh

__all__ = ["encode_map_mcap", "evaluate_map_mcap", "map_mcap"]


def encode_map_mcap(
    messages: Sequence[SceneMessage],
    metadata: dict[str, str],
    stream: Iterable[SceneMessage] = (),
) -> bytes:
    """An MCAP file (bytes) of the messages, written by foxglove-sdk with protobuf
    Foxglove schemas, ordered by log time then topic: same messages, same bytes.

    `stream` (already in that order, e.g. one image per keyframe) is merged in as it is
    read, so its messages are never all in memory at once.
    """
    import foxglove
    import foxglove.messages
    from foxglove.mcap import MCAPWriteOptions

    context = foxglove.Context()  # its own: nothing else logged in this process gets in
    buffer = io.BytesIO()
    options = MCAPWriteOptions(compression_threads=0)
    order = {t: i for i, t in enumerate(TOPIC_SCHEMAS)}
    with foxglove.open_mcap(buffer, context=context, writer_options=options) as writer:
        writer.write_metadata("sonarmap_map", metadata)
        channels: dict[str, Any] = {}

        def key(m: SceneMessage) -> tuple[int, int]:
            return (m.log_time_ns, order[m.topic])

        for m in heapq.merge(sorted(messages, key=key), stream, key=key):
            if m.topic not in channels:  # created as first met: a deterministic order
                schema = getattr(foxglove.messages, TOPIC_SCHEMAS[m.topic]).get_schema()
                channels[m.topic] = foxglove.Channel(
                    m.topic, schema=schema, message_encoding="protobuf", context=context
                )
            channels[m.topic].log(m.message.encode(), log_time=m.log_time_ns)
    return buffer.getvalue()


def map_mcap(
    map_table: pa.Table,
    errors: pa.Table | None,
    keyframes: pa.Table,
    poses: pa.Table,
    objects: pa.Table | None,
    frames: Iterable[KeyframeImages] | None,
    mesh: Mesh | None,
    T_base_sonar: np.ndarray,
    classes: ClassTable = DEFAULT_TABLE,
) -> bytes:
    """evaluate's `map.mcap`: every topic above but the live ones (`/live/fused`, `follow`'s
    preview), maps stamped at the last keyframe, the mesh at the first; class ids those
    of the class table `classes`."""
    t = keyframes.column("t_ns")
    t_first, t_last = (int(pc.min(t).as_py() or 0), int(pc.max(t).as_py() or 0))
    messages = [
        *map_messages(map_table, t_last, errors, classes),
        *trajectory_messages(keyframes, poses),
        *(object_messages(objects, poses, T_base_sonar, classes) if objects is not None else []),
        *(mesh_messages(mesh, t_first) if mesh is not None else []),
    ]
    fused = pc.equal(map_table.column("source"), "fused")
    metadata = {
        "frame": FRAME_MAP,
        "points_fused": str(int(pc.sum(fused).as_py() or 0)),
        "points_total": str(map_table.num_rows),
        "keyframes": str(keyframes.num_rows),
        "has_error_field": str(errors is not None).lower(),
    }
    images = fan_messages(frames) if frames is not None else ()
    return encode_map_mcap(messages, metadata, images)


def evaluate_map_mcap(
    inputs: Mapping[str, Any], errors: pa.Table | None, mesh: Mesh | None
) -> bytes:
    """`map_mcap` of the evaluate stage's inputs, its errors table and decoded mesh."""
    sensors = Sensors.of(inputs["keyframes.sensors"] or {})
    return map_mcap(
        inputs["voxelize.map"],
        errors,
        inputs["keyframes.keyframes"],
        inputs["slam.poses"],
        inputs.get("classify.objects"),
        inputs.get("keyframes.frames"),
        mesh,
        sensors.horizontal.T_base_sonar,
        inputs.get("config.classes", DEFAULT_TABLE),
    )
