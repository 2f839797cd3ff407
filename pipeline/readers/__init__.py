"""Readers: any supported recording -> a `sonarmap.schemas.recording.Recording`.

Formats: ROS 2 MCAP files, rosbag2 directories (mcap or sqlite3 storage, split),
ROS 1 bags (plain, bz2, lz4 chunks) and raw Oculus `SimplePingResult` captures.
Sonar types: ProjectedSonarImage, sonar_oculus OculusPing/OculusPingUncompressed,
polar sensor_msgs Image/CompressedImage (beam table from config). Navigation:
Odometry, PoseStamped, PoseWithCovarianceStamped, or DVL + IMU + depth dead reckoning.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from sonarmap.pipeline.readers.source_types import Source, TopicInfo
from sonarmap.pipeline.readers.sources import dataset_fingerprint_parts, open_source

if TYPE_CHECKING:
    from sonarmap.pipeline.readers.recording import ReaderOptions, SourceRecording

__all__ = [
    "ReaderOptions",
    "Source",
    "SourceRecording",
    "TopicInfo",
    "dataset_fingerprint_parts",
    "open_recording",
    "open_source",
]


def open_recording(path: Path, config: Any = None) -> SourceRecording:
    """Open a recording for the keyframes stage.

    Args:
        path: MCAP file, rosbag2 directory, ROS 1 bag or raw Oculus capture.
        config: the keyframes config (or any object/dict with ReaderOptions' field names).

    Raises:
        SourceError: unreadable file, no/ambiguous sonar or navigation topics.
    """
    from sonarmap.pipeline.readers.recording import ReaderOptions, SourceRecording

    options = ReaderOptions.from_config(config)
    return SourceRecording(open_source(Path(path), options.message_definitions), options)


def __getattr__(name: str) -> Any:
    # The decoders load when a recording is read: fingerprinting a dataset for a cached
    # run (`dataset_fingerprint_parts`) needs none of them.
    if name in ("ReaderOptions", "SourceRecording"):
        from sonarmap.pipeline.readers import recording

        return getattr(recording, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
