"""Write a recording again, slowly, as a recorder would during a dive.

`python -m sonarmap.pipeline.live.replay SOURCE OUT [--speed X] [--chunk-bytes N]`
copies SOURCE's messages to OUT in log-time order with the `mcap` Writer, in small
chunks flushed as they fill, sleeping so that a message is written when its log time
comes (divided by `--speed`). The summary, footer and magic come last, when the copy
ends. It prints `wrote T_NS WALL_S` on stdout for each sonar ping, so a test or benchmark
knows when each ping reached the file; `sonarmap follow OUT` maps it meanwhile.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path

__all__ = ["write_slowly"]

SONAR_HINT = "sonar"
"""Topics whose messages are reported as they are written (the pings)."""


def write_slowly(
    source: Path,
    out: Path,
    *,
    speed: float = 1.0,
    chunk_bytes: int = 4096,
    on_ping: Callable[[int, float], None] | None = None,
) -> int:
    """Copy `source`'s messages (and attachments, after them) to `out`, paced.

    Args:
        source: a finished MCAP file.
        out: the file written (created or truncated at once, finished at the end).
        speed: log-time seconds written per wall-clock second.
        chunk_bytes: the Writer's chunk size: a chunk reaches the file once it holds more.
        on_ping: called with (log time [ns], wall clock [s]) after each sonar message's
            chunk is flushed (a message smaller than `chunk_bytes` may still be buffered).

    Returns:
        The number of messages written.
    """
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    count = 0
    with source.open("rb") as src, out.open("wb") as dst:
        reader = make_reader(src)
        header = reader.get_header()
        writer = Writer(dst, chunk_size=chunk_bytes, compression=CompressionType.ZSTD)
        writer.start(profile=header.profile, library=header.library)
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        start_wall = time.time()
        first: int | None = None
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            first = message.log_time if first is None else first
            due = start_wall + (message.log_time - first) / 1e9 / speed
            if due > time.time():
                time.sleep(due - time.time())
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic,
                    channel.message_encoding,
                    schemas.get(channel.schema_id, 0),
                    dict(channel.metadata),
                )
            writer.add_message(
                channels[channel.id],
                message.log_time,
                message.data,
                message.publish_time,
                message.sequence,
            )
            dst.flush()
            count += 1
            if on_ping is not None and SONAR_HINT in channel.topic and "/" in channel.topic:
                on_ping(message.log_time, time.time())
        for attachment in reader.iter_attachments():
            writer.add_attachment(
                attachment.create_time,
                attachment.log_time,
                attachment.name,
                attachment.media_type,
                attachment.data,
            )
        for metadata in reader.iter_metadata():
            writer.add_metadata(metadata.name, dict(metadata.metadata))
        writer.finish()
    return count


def main(argv: list[str]) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m sonarmap.pipeline.live.replay")
    parser.add_argument("source", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--speed", type=float, default=1.0)
    parser.add_argument("--chunk-bytes", type=int, default=4096)
    args = parser.parse_args(argv)

    def report(t_ns: int, wall: float) -> None:
        print(f"wrote {t_ns} {wall:.3f}", flush=True)

    n = write_slowly(
        args.source, args.out, speed=args.speed, chunk_bytes=args.chunk_bytes, on_ping=report
    )
    print(f"done {n} {time.time():.3f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
