"""Hostile sonar mountings (issue 36 item 2, the geometry module): a recording whose
/tf_static gives a sonar a rotation quaternion of zero or non-finite norm, or a
non-finite translation. `sonarmap.stages.kernels.geometry.matrix_from_quat` refuses such a
quaternion and the reader turns it into one `error:` line naming the file, the topic
and the transform, exit 2 (it used to become a NaN mounting that placed every point of
that sonar nowhere).

Each case copies the small simulated recording and rewrites its /tf_static message.
"""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tests.contract.case import Case, names
from tests.fixtures import small_recording

NAN, INF = float("nan"), float("inf")
TF_TYPE = "tf2_msgs/msg/TFMessage"
REC = "recs/dive.mcap"


def _rewrite_tf(src: Path, dst: Path, edit: Callable[[Any], None]) -> None:
    """Copy an MCAP record by record, passing each /tf_static message through `edit`."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    from sonarmap.pipeline.formats.rosmsg import ros2_typestore
    from sonarmap.schemas.topics import TOPIC_TF_STATIC

    store = ros2_typestore()
    with src.open("rb") as f, dst.open("wb") as out:
        reader = make_reader(f)
        writer = Writer(out, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="qa-geo")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, m in reader.iter_messages(log_time_order=False):
            assert schema is not None
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id], channel.metadata
                )
            data = m.data
            if channel.topic == TOPIC_TF_STATIC:
                msg = store.deserialize_cdr(data, TF_TYPE)
                edit(msg)
                data = bytes(store.serialize_cdr(msg, TF_TYPE))
            writer.add_message(channels[channel.id], m.log_time, data, m.publish_time, m.sequence)
        for a in reader.iter_attachments():
            writer.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        for md in reader.iter_metadata():
            writer.add_metadata(md.name, md.metadata)
        writer.finish()


def _mount(
    sonar: str,
    quat: tuple[float, float, float, float] | None = None,
    xyz: tuple[float, ...] | None = None,
) -> Callable[[Path], list[str]]:
    """A case input: the recording with `sonar`'s /tf_static rotation and/or translation set."""

    def edit(msg: Any) -> None:
        from sonarmap.pipeline.formats.rosmsg import ros2_typestore
        from sonarmap.schemas.topics import FRAME_SONAR

        t = ros2_typestore().types
        for tf in msg.transforms:
            if tf.child_frame_id.lstrip("/") != FRAME_SONAR[sonar]:
                continue
            if quat is not None:
                x, y, z, w = quat
                tf.transform.rotation = t["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)
            if xyz is not None:
                tf.transform.translation = t["geometry_msgs/msg/Vector3"](
                    x=xyz[0], y=xyz[1], z=xyz[2]
                )

    def build(work: Path) -> list[str]:
        clean = small_recording(work / "clean.mcap", seed=2, duration_s=15.0)
        (work / REC).parent.mkdir(parents=True, exist_ok=True)
        _rewrite_tf(clean, work / REC, edit)
        clean.unlink()
        return ["run", REC]

    return build


def _refused(
    sonar: str, what: str
) -> Callable[[Path, subprocess.CompletedProcess[str]], str | None]:
    from sonarmap.schemas.topics import FRAME_SONAR

    return names("dive.mcap", "/tf_static", f"base_link -> {FRAME_SONAR[sonar]}", what)


_QUAT = "zero or non-finite norm"
_XYZ = "translation is not finite"

CASES = [
    Case(
        "exit codes",
        "tf_static: zero quaternion (horizontal)",
        _mount("horizontal", (0, 0, 0, 0)),
        check=_refused("horizontal", _QUAT),
    ),
    Case(
        "exit codes",
        "tf_static: zero quaternion (vertical)",
        _mount("vertical", (0, 0, 0, 0)),
        check=_refused("vertical", _QUAT),
    ),
    Case(
        "exit codes",
        "tf_static: NaN in w",
        _mount("horizontal", (0, 0, 0, NAN)),
        check=_refused("horizontal", _QUAT),
    ),
    Case(
        "exit codes",
        "tf_static: NaN in x of a unit-looking quaternion",
        _mount("vertical", (NAN, 0, 0, 1)),
        check=_refused("vertical", _QUAT),
    ),
    Case(
        "exit codes",
        "tf_static: +inf in z",
        _mount("horizontal", (0, 0, INF, 1)),
        check=_refused("horizontal", _QUAT),
    ),
    Case(
        "exit codes",
        "tf_static: -inf in y",
        _mount("vertical", (0, -INF, 0, 1)),
        check=_refused("vertical", _QUAT),
    ),
    Case(
        "exit codes",
        "tf_static: all four NaN",
        _mount("horizontal", (NAN, NAN, NAN, NAN)),
        check=_refused("horizontal", _QUAT),
    ),
    Case(
        "exit codes",
        "tf_static: components overflowing the norm (1e300)",
        _mount("horizontal", (1e300, 1e300, 0, 0)),
        check=_refused("horizontal", _QUAT),
    ),
    Case(
        "exit codes",
        "tf_static: NaN translation x",
        _mount("horizontal", xyz=(NAN, 0.0, 0.0)),
        check=_refused("horizontal", _XYZ),
    ),
    Case(
        "exit codes",
        "tf_static: +inf translation z",
        _mount("vertical", xyz=(0.5, 0.0, INF)),
        check=_refused("vertical", _XYZ),
    ),
    Case(
        "exit codes",
        "tf_static: -inf translation y and zero quaternion",
        _mount("vertical", (0, 0, 0, 0), (0.5, -INF, 0.0)),
        check=_refused("vertical", _XYZ),
    ),
]
