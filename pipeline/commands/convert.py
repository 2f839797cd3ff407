"""`sonarmap convert INPUT -o OUT.mcap`: any supported recording -> a ROS 2 MCAP.

Sonars become `marine_acoustic_msgs/msg/ProjectedSonarImage` on /sonar/horizontal and
/sonar/vertical (with their label/truth images when present), navigation becomes
`nav_msgs/msg/Odometry` on /odometry/dead_reckoning (dead reckoning computed when the
input has only DVL + IMU + depth), ground truth on /ground_truth/odometry, the sonar
mounts the recording (or config) gives on /tf_static (base_link -> sonar_*, chains
composed; a sonar without one gets none, never a default), attachments copied. Streaming: memory does not grow with the recording.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterator
from pathlib import Path
from typing import Any, BinaryIO

import typer

from sonarmap.pipeline.commands._common import JSON_OPT, emit_json

__all__ = ["convert_recording", "register"]


def _odometry(t_ns: int, xyz: Any, rpy: Any, child: str) -> Any:
    import numpy as np

    from sonarmap.pipeline.formats.rosmsg import ros2_typestore
    from sonarmap.schemas.topics import FRAME_ODOM
    from sonarmap.stages.kernels.geometry import quat_from_rpy

    t = ros2_typestore().types
    q = quat_from_rpy(np.asarray(rpy, np.float64)).tolist()
    vec = t["geometry_msgs/msg/Vector3"]
    return t["nav_msgs/msg/Odometry"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9),
            frame_id=FRAME_ODOM,
        ),
        child_frame_id=child,
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](
                    x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2])
                ),
                orientation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            ),
            covariance=np.zeros(36),
        ),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](
                linear=vec(x=0.0, y=0.0, z=0.0), angular=vec(x=0.0, y=0.0, z=0.0)
            ),
            covariance=np.zeros(36),
        ),
    )


def _tf_static(t_ns: int, mounts: dict[str, Any]) -> Any:
    from scipy.spatial.transform import Rotation

    from sonarmap.pipeline.formats.rosmsg import ros2_typestore
    from sonarmap.schemas.topics import FRAME_BASE, FRAME_SONAR

    t = ros2_typestore().types
    stamp = t["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
    transforms = []
    for sonar, T in sorted(mounts.items()):
        qx, qy, qz, qw = Rotation.from_matrix(T[:3, :3]).as_quat()
        transforms.append(
            t["geometry_msgs/msg/TransformStamped"](
                header=t["std_msgs/msg/Header"](stamp=stamp, frame_id=FRAME_BASE),
                child_frame_id=FRAME_SONAR[sonar],
                transform=t["geometry_msgs/msg/Transform"](
                    translation=t["geometry_msgs/msg/Vector3"](x=T[0, 3], y=T[1, 3], z=T[2, 3]),
                    rotation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
                ),
            )
        )
    return t["tf2_msgs/msg/TFMessage"](transforms=transforms)


def _sonar_events(rec: Any, sonar: str, order: int) -> Iterator[tuple[int, int, str, str, Any]]:
    import numpy as np

    from sonarmap.pipeline.formats.frames_io import image_message, sonar_cdr
    from sonarmap.schemas.topics import (
        FRAME_SONAR,
        IMAGE_TYPE,
        LABEL_TOPIC,
        PROJECTED_SONAR_TYPE,
        SONAR_TOPIC,
        TRUTH_ANGLE_TOPIC,
    )

    n = len(rec.ping_times_ns(sonar))
    frame = FRAME_SONAR[sonar]
    for ping in rec.pings(sonar, np.arange(n)):
        yield ping.t_ns, order, SONAR_TOPIC[sonar], PROJECTED_SONAR_TYPE, sonar_cdr(ping, frame)
        if ping.labels is not None:
            yield (
                ping.t_ns,
                order + 1,
                LABEL_TOPIC[sonar],
                IMAGE_TYPE,
                image_message(ping.labels, ping.t_ns, frame),
            )
        if ping.truth_angle_rad is not None:
            msg = image_message(ping.truth_angle_rad.astype(np.float32), ping.t_ns, frame)
            yield ping.t_ns, order + 2, TRUTH_ANGLE_TOPIC[sonar], IMAGE_TYPE, msg


def _track_events(track: Any, topic: str, order: int) -> Iterator[tuple[int, int, str, str, Any]]:
    from sonarmap.schemas.topics import FRAME_BASE, ODOMETRY_TYPE

    for k in range(len(track)):
        t = int(track.t_ns[k])
        yield (
            t,
            order,
            topic,
            ODOMETRY_TYPE,
            _odometry(t, track.xyz_m[k], track.rpy_rad[k], FRAME_BASE),
        )


def convert_recording(src: Path, dst: Path, options: Any = None) -> dict[str, Any]:
    """Convert any supported recording into a ROS 2 MCAP; returns counts per topic."""
    from sonarmap.pipeline.engine.errors import SourceError
    from sonarmap.pipeline.formats.atomic import atomic_output
    from sonarmap.pipeline.readers import ReaderOptions, SourceRecording, open_source
    from sonarmap.pipeline.readers.roles import detect_roles
    from sonarmap.schemas.topics import TOPIC_DEAD_RECKONING, TOPIC_GROUND_TRUTH

    opts = ReaderOptions.from_config(options)
    source = open_source(src, opts.message_definitions)
    roles = detect_roles(src, source.topics(), opts, require_pair=False)
    if not roles.sonar:
        from sonarmap.pipeline.readers.roles import topic_listing

        raise SourceError(
            f"{src}: no sonar topic found (topics: {topic_listing(source.topics())}); "
            "set keyframes.horizontal_topic / keyframes.vertical_topic"
        )
    rec = SourceRecording(source, opts, roles)
    streams = [_sonar_events(rec, s, 10 * i) for i, s in enumerate(sorted(roles.sonar))]
    streams.append(_track_events(rec.navigation(), TOPIC_DEAD_RECKONING, 30))
    truth = rec.ground_truth()
    if truth is not None:
        streams.append(_track_events(truth, TOPIC_GROUND_TRUTH, 31))
    counts: dict[str, int] = {}
    # Written beside `dst` and renamed on success: a recording that turns out unreadable
    # half-way never replaces (or leaves behind) an output file.
    with atomic_output(dst) as f:
        _write(f, rec, roles, streams, counts, src, source.kind)
    return {
        "input": str(src),
        "output": str(dst),
        "format": source.kind,
        "roles": roles.as_dict(),
        "topics": dict(sorted(counts.items())),
        "provenance": rec.provenance(),
        "warnings": list(source.warnings),
    }


def _write(
    f: BinaryIO,
    rec: Any,
    roles: Any,
    streams: list[Iterator[Any]],
    counts: dict[str, int],
    src: Path,
    kind: str,
) -> None:
    """Stream every event into a new MCAP written to `f`; `counts` filled per topic."""
    from sonarmap.pipeline.formats.rosmsg import recording_writer
    from sonarmap.schemas.topics import TOPIC_TF_STATIC

    first = True
    with recording_writer(f) as w:
        for t, _, topic, typ, msg in heapq.merge(*streams, key=lambda e: (e[0], e[1])):
            if first:
                mounts = _recorded_mounts(rec, roles)
                if mounts:
                    w.write(TOPIC_TF_STATIC, "tf2_msgs/msg/TFMessage", _tf_static(t, mounts), t)
                    counts[TOPIC_TF_STATIC] = 1
                first = False
            if isinstance(msg, bytes):
                w.write_raw(topic, typ, msg, t)
            else:
                w.write(topic, typ, msg, t)
            counts[topic] = counts.get(topic, 0) + 1
        for name, data in sorted(rec.attachments().items()):
            w.add_attachment(name, data, "application/octet-stream")
        w.add_metadata("sonarmap.convert", {"source": src.name, "format": kind})


def _recorded_mounts(rec: Any, roles: Any) -> dict[str, Any]:
    """The sonar mounts the recording (or the user's config) gives: a default mount is not
    written, so mount settings on the converted file still apply (it has none to override)."""
    mounts = rec.mountings()
    provenance = rec.provenance()
    return {
        s: mounts[s]
        for s in roles.sonar
        if "default" not in (provenance[f"{s}_sonar"].get(f"mount_{p}") for p in ("xyz", "rpy"))
    }


def _vector(item: str, value: str) -> Any:
    """`[x, y, z]` -> a tuple of floats (a mount); any other text stays a string."""
    from sonarmap.pipeline.engine.errors import ConfigError

    if not value.strip().startswith("["):
        return value
    try:
        return tuple(float(v) for v in value.strip()[1:-1].split(","))
    except ValueError:
        raise ConfigError(f"--set {item[:80]!r}: expected [x, y, z] numbers") from None


def _parse_sets(items: list[str] | None) -> dict[str, Any]:
    from sonarmap.pipeline.engine.errors import ConfigError

    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep:
            raise ConfigError(
                f"--set {item[:80]!r}: expected key=value (e.g. keyframes.horizontal_topic=/sonar)"
            )
        key = key.strip().removeprefix("keyframes.")
        if key not in _reader_fields():
            import difflib

            near = difflib.get_close_matches(key, sorted(_reader_fields()), n=1)
            hint = f"; did you mean keyframes.{near[0]}?" if near else ""
            raise ConfigError(
                f"--set {item[:80]!r}: not a reader option; convert takes the keyframes"
                f" section's topic, frame, mount and navigation settings only"
                f" (`sonarmap config dump` shows them){hint}"
            )
        if _is_text(key):
            out[key] = value
            continue
        try:
            out[key] = float(value)
        except ValueError:
            out[key] = _vector(item, value)
    _check_reader_values(out)
    return out


def _reader_fields() -> frozenset[str]:
    """The keyframes settings the reader takes (`ReaderOptions`): convert's options."""
    from dataclasses import fields

    from sonarmap.pipeline.readers import ReaderOptions

    return frozenset(f.name for f in fields(ReaderOptions))


def _check_reader_values(options: dict[str, Any]) -> None:
    """Each value checked as `run` checks it, by the keyframes section's own model."""
    from pydantic import ValidationError

    from sonarmap.pipeline.engine.errors import ConfigError
    from sonarmap.stages.keyframes import KeyframesConfig

    try:
        KeyframesConfig.model_validate(options)
    except ValidationError as err:
        first = err.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise ConfigError(f"--set keyframes.{where}: {first['msg']}") from None


def _is_text(key: str) -> bool:
    """Whether the keyframes field `key` holds text (a topic or frame name): its value is
    kept as given, never read as a number."""
    from sonarmap.stages.keyframes import KeyframesConfig

    field = KeyframesConfig.model_fields.get(key)
    return field is not None and "str" in str(field.annotation)


def _input_files(source: Path) -> list[Path]:
    """The files `convert` reads: the source, and a bag directory's own files (at most
    1000 looked at: an output among more is caught when it is renamed into place)."""
    if not source.is_dir():
        return [source]
    files = [source]
    for k, entry in enumerate(source.iterdir()):
        if k >= 1000:
            break
        files.append(entry)
    return files


def register(app: typer.Typer) -> None:
    """Add the `convert` command."""

    @app.command("convert")
    def convert(
        source: Path = typer.Argument(
            ..., help="MCAP file, ROS 2 bag directory, ROS 1 bag or raw Oculus capture."
        ),
        output: Path = typer.Option(..., "--output", "-o", help="Output .mcap path."),
        set_: list[str] | None = typer.Option(
            None,
            "--set",
            "-s",
            help="Reader option, e.g. keyframes.horizontal_topic=/ping. Repeatable.",
        ),
        json_: bool = JSON_OPT,
    ) -> None:
        """Convert a recording into a ROS 2 MCAP with ProjectedSonarImage sonar topics."""
        from sonarmap.pipeline.engine.errors import SourceError

        if not output.parent.is_dir():
            raise SourceError(f"output directory {output.parent} does not exist")
        from sonarmap.pipeline.formats.atomic import check_output_path

        check_output_path(output, _input_files(source))  # before any work
        options = _parse_sets(set_)
        from sonarmap.pipeline.commands._common import logged_warnings

        with logged_warnings() as seen:
            report = convert_recording(source, output, options)
        if json_:
            emit_json(report)
            return
        # The reader's warnings that were collected but not logged (ARIS's), as `topics`.
        from sonarmap.pipeline.commands._errors import one_line

        for line in report["warnings"]:
            if line not in seen:
                typer.echo(f"warning: {one_line(line)}", err=True)
        typer.echo(
            f"wrote {output}: " + ", ".join(f"{k} {v}" for k, v in report["topics"].items()),
            err=True,
        )
