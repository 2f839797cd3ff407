"""Write a recording again, slowly, as a recorder would during a dive.

`python -m sonarmap.pipeline.live.replay SOURCE OUT [--speed X] [--chunk-bytes N]
[--split-s S]` copies SOURCE's messages to OUT in log-time order with the `mcap` Writer,
in small chunks flushed as they fill, sleeping so that a message is written when its log
time comes (divided by `--speed`). The summary, footer and magic come last, when the copy
ends. With `--split-s`, OUT is a rosbag2 directory whose split files open one after the
other every S s of log time, and whose `metadata.yaml` is written at the end. With
`--log-writes` it prints `wrote T_NS WALL_S` on stdout for each sonar ping, so a test or
benchmark knows when each ping reached the file; `sonarmap follow OUT` maps it meanwhile.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["write_slowly"]

SONAR_HINT = "sonar"
"""Topics whose messages are reported as they are written (the pings)."""


def write_slowly(
    source: Path,
    out: Path,
    *,
    speed: float = 1.0,
    chunk_bytes: int = 4096,
    split_s: float | None = None,
    on_ping: Callable[[int, float], None] | None = None,
) -> int:
    """Copy `source`'s messages (and attachments, after them) to `out`, paced.

    Args:
        source: a finished MCAP file.
        out: the file written (created or truncated at once, finished at the end); with
            `split_s`, a rosbag2 directory: `OUT_0.mcap`, `OUT_1.mcap`, ... as
            `ros2 bag record -s mcap` splits them, and `metadata.yaml` at the end.
        speed: log-time seconds written per wall-clock second.
        chunk_bytes: the Writer's chunk size: a chunk reaches the file once it holds more.
        split_s: log-time seconds per split file (None: one MCAP file).
        on_ping: called with (log time [ns], wall clock [s]) after each sonar message's
            chunk is flushed (a message smaller than `chunk_bytes` may still be buffered).

    Returns:
        The number of messages written.
    """
    from mcap.reader import make_reader

    with source.open("rb") as src:
        reader = make_reader(src)
        bag = _Output(out, reader.get_header(), chunk_bytes, split_s)
        start_wall = time.time()
        first: int | None = None
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            first = message.log_time if first is None else first
            due = start_wall + (message.log_time - first) / 1e9 / speed
            if due > time.time():
                time.sleep(due - time.time())
            bag.add(schema, channel, message, message.log_time - first)
            if on_ping is not None and SONAR_HINT in channel.topic:
                on_ping(message.log_time, time.time())
        bag.finish(list(reader.iter_attachments()), list(reader.iter_metadata()))
    return bag.count


class _Output:
    """The MCAP file being written, or the split files of a bag directory."""

    def __init__(self, out: Path, header: Any, chunk_bytes: int, split_s: float | None) -> None:
        self.out, self.header, self.chunk_bytes, self.split_s = out, header, chunk_bytes, split_s
        self.files: list[str] = []
        self.count = 0
        self.counts: dict[tuple[str, str], int] = {}  # (topic, type) -> messages
        self.first_ns: int | None = None
        self.last_ns = 0
        if split_s is not None:
            out.mkdir(parents=True, exist_ok=True)
        self._open()

    def _open(self) -> None:
        from mcap.writer import CompressionType, Writer

        if self.split_s is None:
            path = self.out
        else:
            self.files.append(f"{self.out.name}_{len(self.files)}.mcap")
            path = self.out / self.files[-1]
        self._file = path.open("wb")
        self._writer = Writer(
            self._file, chunk_size=self.chunk_bytes, compression=CompressionType.ZSTD
        )
        self._writer.start(profile=self.header.profile, library=self.header.library)
        self._schemas: dict[int, int] = {}
        self._channels: dict[int, int] = {}

    def add(self, schema: Any, channel: Any, message: Any, since_first_ns: int) -> None:
        if self.split_s is not None and since_first_ns >= self.split_s * 1e9 * len(self.files):
            self._close()  # the recorder splits: this file is finished, the next opens
            self._open()
        w = self._writer
        if schema is not None and schema.id not in self._schemas:
            self._schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
        if channel.id not in self._channels:
            self._channels[channel.id] = w.register_channel(
                channel.topic,
                channel.message_encoding,
                self._schemas.get(channel.schema_id, 0),
                dict(channel.metadata),
            )
        w.add_message(
            self._channels[channel.id],
            message.log_time,
            message.data,
            message.publish_time,
            message.sequence,
        )
        self._file.flush()
        self.count += 1
        key = (channel.topic, schema.name if schema is not None else "")
        self.counts[key] = self.counts.get(key, 0) + 1
        self.first_ns = message.log_time if self.first_ns is None else self.first_ns
        self.last_ns = max(self.last_ns, message.log_time)

    def _close(self) -> None:
        self._writer.finish()
        self._file.close()

    def finish(self, attachments: list[Any], metadata: list[Any]) -> None:
        for a in attachments:
            self._writer.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        for m in metadata:
            self._writer.add_metadata(m.name, dict(m.metadata))
        self._close()
        if self.split_s is not None:
            self._write_metadata()

    def _write_metadata(self) -> None:
        import yaml

        topics = [
            {
                "message_count": n,
                "topic_metadata": {
                    "name": topic,
                    "type": msgtype,
                    "serialization_format": "cdr",
                    "offered_qos_profiles": "",
                },
            }
            for (topic, msgtype), n in sorted(self.counts.items())
        ]
        info = {
            "version": 5,
            "storage_identifier": "mcap",
            "relative_file_paths": self.files,
            "duration": {"nanoseconds": self.last_ns - (self.first_ns or 0)},
            "starting_time": {"nanoseconds_since_epoch": self.first_ns or 0},
            "message_count": self.count,
            "topics_with_message_count": topics,
            "compression_format": "",
            "compression_mode": "",
        }
        tmp = self.out / "metadata.yaml.tmp"  # written whole, then renamed: as a recorder
        tmp.write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}))
        tmp.replace(self.out / "metadata.yaml")


def main(argv: list[str]) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m sonarmap.pipeline.live.replay")
    parser.add_argument("source", type=Path, help="a closed recording (MCAP file)")
    parser.add_argument("out", type=Path, help="the MCAP file (or bag directory) to write")
    parser.add_argument("--speed", type=float, default=1.0, help="times the recording's pace")
    parser.add_argument("--chunk-bytes", type=int, default=4096, help="MCAP chunk size")
    parser.add_argument("--split-s", type=float, default=None, help="write a bag directory")
    parser.add_argument(
        "--log-writes",
        action="store_true",
        help="print 'wrote T_NS WALL_S' for each sonar ping and 'done N WALL_S' at the end",
    )
    args = parser.parse_args(argv)

    def report(t_ns: int, wall: float) -> None:
        if args.log_writes:
            print(f"wrote {t_ns} {wall:.3f}", flush=True)

    start = time.time()
    n = write_slowly(
        args.source,
        args.out,
        speed=args.speed,
        chunk_bytes=args.chunk_bytes,
        split_s=args.split_s,
        on_ping=report,
    )
    if args.log_writes:
        print(f"done {n} {time.time():.3f}", flush=True)
    print(
        f"replay: wrote {n} messages to {args.out} in {time.time() - start:.1f} s", file=sys.stderr
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
