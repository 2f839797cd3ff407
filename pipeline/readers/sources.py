"""Raw message sources: one interface over MCAP files, rosbag2 directories, ROS 1 bags,
raw Oculus captures and ARIS recordings.

A source lists its topics (type, count, time span) and streams `(topic, t_ns, message)`
in log-time order, deserialising only the messages asked for. Times are log (receive)
times in integer nanoseconds; they are what pairs the sonars and the navigation.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.readers.source_types import Source

__all__ = [
    "dataset_fingerprint_parts",
    "open_source",
]

log = logging.getLogger(__name__)


def _sniff(path: Path) -> str:
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return "rosbag2"
        raise SourceError(f"{path}: a directory without metadata.yaml is not a ROS 2 bag")
    if not path.is_file():
        if path.exists():
            raise SourceError(f"{path}: not a regular file (a FIFO, device or socket)")
        raise SourceError(f"{path}: no such file")
    size = path.stat().st_size
    if size == 0:
        raise SourceError(f"{path}: empty file (0 bytes), no topics")
    with path.open("rb") as f:
        head = f.read(16)
    if head.startswith(b"\x89MCAP"):
        return "mcap"
    if head.startswith(b"#ROSBAG V2.0"):
        return "rosbag1"
    if head[:2] == b"SO":
        return "oculus-raw"
    if head.startswith(b"SQLite format 3"):
        return "sqlite3"
    if head.startswith(b"DDF\x05"):
        return "aris"
    raise SourceError(
        f"{path}: not a recording sonarmap can read (expected MCAP, ROS 1 bag, ROS 2 bag "
        "directory, raw Oculus capture or ARIS file)"
    )


def open_source(path: Path, message_definitions: Sequence[str | Path] = ()) -> Source:
    """Open any supported recording as a `Source` (SourceError when it cannot be read).

    Args:
        path: the recording.
        message_definitions: `.msg` / `.idl` files of custom types, for the formats that
            carry no definitions of their own (rosbag2 sqlite3); MCAP and ROS 1 bags embed them.
    """
    path = Path(path)
    kind = _sniff(path)
    extra = None
    if message_definitions:
        from sonarmap.pipeline.readers.typestores import load_message_types

        extra = load_message_types(message_definitions)
    if kind == "mcap":
        from sonarmap.pipeline.readers.mcap_source import McapSource

        return McapSource(path, [path])
    if kind == "rosbag1":
        from sonarmap.pipeline.readers.ros1_source import Ros1Source

        return Ros1Source(path)
    if kind == "oculus-raw":
        from sonarmap.pipeline.readers.oculus_raw import OculusRawSource

        return OculusRawSource(path)
    if kind == "sqlite3":
        from sonarmap.pipeline.readers.sqlite_source import SqliteSource

        return SqliteSource(path, [path], None, extra)
    if kind == "aris":
        from sonarmap.pipeline.readers.aris import ArisSource

        return ArisSource(path)
    return _open_rosbag2(path, extra)


def _bag_metadata(path: Path) -> dict[str, Any]:
    from sonarmap.pipeline.engine.config.yaml_files import read_yaml

    meta = path / "metadata.yaml"
    doc = read_yaml(meta, "bag metadata", SourceError)
    try:
        return dict(doc["rosbag2_bagfile_information"])
    except (KeyError, TypeError, ValueError) as err:
        raise SourceError(
            f"{meta}: not a rosbag2 metadata file (no mapping 'rosbag2_bagfile_information')"
        ) from err


def _listed_files(path: Path, meta: dict[str, Any]) -> list[Path]:
    """The data files a bag's metadata.yaml lists, each inside the bag directory.

    Raises:
        SourceError: `relative_file_paths` is not a list of names, or one of them is
            absolute or leads out of the directory (`..`): a bag names its own files.
    """
    names = meta.get("relative_file_paths", [])
    where = path / "metadata.yaml"
    if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names):
        raise SourceError(f"{where}: relative_file_paths is not a list of file names")
    files = []
    for name in names:
        # By the name, not where it leads: a bag of symbolic links to the files (a user's
        # own layout) is read as it is; a name that climbs out or starts at / is not.
        if Path(name).is_absolute() or os.path.normpath(name).split(os.sep)[0] == "..":
            raise SourceError(
                f"{where}: relative_file_paths lists {name[:120]!r}, outside the bag directory"
            )
        if os.path.normpath(path / name) in map(os.path.normpath, files):
            raise SourceError(f"{where}: relative_file_paths lists {name[:120]!r} twice")
        files.append(path / name)
    return files


def _check_mcap_magic(files: list[Path]) -> None:
    """SourceError naming the first listed file that does not start as an MCAP file."""
    from sonarmap.pipeline.readers.mcap_scan import MAGIC

    for file in files:
        with file.open("rb") as f:
            head = f.read(len(MAGIC))
        if head != MAGIC:
            raise SourceError(
                f"{file}: not an MCAP file (no MCAP magic at byte 0), though the bag's "
                "metadata.yaml says its storage is mcap"
            )


def _open_rosbag2(path: Path, extra_types: dict[str, Any] | None = None) -> Source:
    meta = _bag_metadata(path)
    files = _listed_files(path, meta)
    if not files:
        raise SourceError(f"{path / 'metadata.yaml'}: relative_file_paths lists no file")
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise SourceError(
            f"{path}: bag files listed in metadata.yaml are missing: {missing[0]}"
            + (f" and {len(missing) - 1} more" if len(missing) > 1 else "")
        )
    # A metadata.yaml listing no topics claims no counts (`follow`'s snapshot of a bag
    # being written cannot know them): nothing to check the messages against.
    indexed = (
        {
            t["topic_metadata"]["name"]: int(t.get("message_count", 0))
            for t in meta["topics_with_message_count"]
        }
        if "topics_with_message_count" in meta
        else None
    )
    storage = meta.get("storage_identifier", "")
    if storage == "mcap":
        from sonarmap.pipeline.readers.mcap_source import McapSource

        _check_mcap_magic(files)
        return McapSource(path, files, indexed)
    if storage == "sqlite3":
        from sonarmap.pipeline.readers.sqlite_source import SqliteSource

        return SqliteSource(path, files, indexed, extra_types)
    raise SourceError(f"{path}: unsupported rosbag2 storage {storage!r} (mcap or sqlite3)")


def dataset_fingerprint_parts(path: Path) -> list[Path]:
    """The files whose content makes up a dataset, sorted (a bag directory has several).

    Args:
        path: a recording file or a rosbag2 directory.

    Returns:
        Absolute paths of every data file (and `metadata.yaml` for a bag directory).
    """
    path = Path(path)
    if path.is_dir():
        meta = _bag_metadata(path)
        files = [path / "metadata.yaml", *_listed_files(path, meta)]
        return sorted(f.resolve() for f in files)
    if not path.is_file():
        if path.exists():
            raise SourceError(f"{path}: not a regular file (a FIFO, device or socket)")
        raise SourceError(f"{path}: no such file")
    return [path.resolve()]
