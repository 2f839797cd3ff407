"""The `Recording` protocol: what the keyframes stage reads from a raw dataset.

The engine opens a dataset (MCAP, rosbag2 directory, ROS 1 bag, ...) with
`sonarmap.pipeline.readers.open_recording` and binds it to the keyframes stage's "dataset"
input. Everything here is arrays in memory except the sonar images, which are decoded
on demand by `pings`, so memory does not grow with the recording.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from sonarmap.schemas.sonar import SonarPing

__all__ = ["PoseTrack", "Recording"]


@dataclass(frozen=True)
class PoseTrack:
    """A time series of 6-DoF vehicle poses (base_link in the odom/world frame, REP 103).

    Attributes:
        t_ns: (n,) int64 times [ns], strictly ascending.
        xyz_m: (n, 3) float64 position [m].
        rpy_rad: (n, 3) float64 roll, pitch, yaw [rad] (extrinsic x-y-z, R = Rz Ry Rx).
    """

    t_ns: np.ndarray
    xyz_m: np.ndarray
    rpy_rad: np.ndarray

    def __len__(self) -> int:
        return len(self.t_ns)


@runtime_checkable
class Recording(Protocol):
    """A raw dataset opened for the keyframes stage.

    Sonars are named "horizontal" and "vertical" (schemas.topics.SONARS).
    """

    @property
    def name(self) -> str:
        """Human-readable dataset name (file name), for messages only."""
        ...

    @property
    def has_labels(self) -> bool:
        """Whether both sonars carry per-pixel class label images."""
        ...

    @property
    def has_ground_truth(self) -> bool:
        """Whether a ground-truth pose stream exists."""
        ...

    def ping_times_ns(self, sonar: str) -> np.ndarray:
        """(n,) int64 ascending times [ns] of every ping of one sonar; index = ping index."""
        ...

    def navigation(self) -> PoseTrack:
        """The dead-reckoning/navigation pose stream the keyframes are posed with."""
        ...

    def ground_truth(self) -> PoseTrack | None:
        """The true pose stream (simulator), or None."""
        ...

    def pings(
        self, sonar: str, indices: Sequence[int] | np.ndarray, labels: bool = True
    ) -> Iterator[SonarPing]:
        """Decode only the requested pings, streaming, one `SonarPing` per index.

        Args:
            sonar: "horizontal" or "vertical".
            indices: non-decreasing ping indices into `ping_times_ns(sonar)`.
            labels: also decode the label and truth images, where the recording has
                them (False: the pings' `labels` and `truth_angle_rad` are None).
        """
        ...

    def mountings(self) -> dict[str, np.ndarray]:
        """{sonar: (4, 4) float64 T_base_sonar} from /tf_static or config defaults."""
        ...

    def attachments(self) -> dict[str, bytes]:
        """Named attachments of the dataset (e.g. "scene.ply": the true scene mesh)."""
        ...

    def describe(self) -> dict[str, object]:
        """JSON-able facts about the source (format, topics used, warnings)."""
        ...
