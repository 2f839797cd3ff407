"""Sensor geometry of a recording: each sensor's mount in base_link, and its provenance.

A sensor's frame is the `header.frame_id` of its messages; its mount is base_link -> that
frame composed through the recording's `/tf_static` (and `/tf`) tree. Config set for a
sensor overrides the recording (said in a warning); where neither gives a mount, the
default applies, with a warning. Every role's topic, type, frame and the source of each
value ("recording", "config", "default") is kept for the keyframes artifact and the run
summary.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from sonarmap.pipeline.readers.roles import Roles
from sonarmap.pipeline.readers.source_types import Source
from sonarmap.pipeline.readers.tf_tree import TfTree, normalise_frame
from sonarmap.schemas.recording import PoseTrack
from sonarmap.schemas.topics import FRAME_SONAR, SONARS
from sonarmap.stages.kernels.geometry import matrix_from_rpy, se3

__all__ = ["DEFAULT_SONAR_MOUNTS", "SensorGeometry", "message_frame", "mounting_matrix"]


def message_frame(msg: Any) -> str:
    """A message's frame: `header.frame_id` (or the fast sonar parse's `frame_id`)."""
    frame = getattr(msg, "frame_id", None)
    if frame is None:
        frame = getattr(getattr(msg, "header", None), "frame_id", "")
    return normalise_frame(str(frame or ""))


DEFAULT_SONAR_MOUNTS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "horizontal": ((0.5, 0.0, 0.0), (0.0, 0.0, 0.0)),
    "vertical": ((0.5, 0.0, 0.1), (90.0, 0.0, 0.0)),
}
"""(xyz [m], rpy [deg]) of each sonar in base_link when neither config nor the recording
gives one (the simulator's mounting; docs/architecture.md#conventions)."""

_UNIT = {"xyz": "_m", "rpy": "_deg"}


def mounting_matrix(
    xyz: Sequence[float] | np.ndarray, rpy_rad: Sequence[float] | np.ndarray
) -> np.ndarray:
    """(4, 4) T_parent_child from a translation [m] and roll/pitch/yaw [rad] (R = Rz Ry Rx)."""
    return se3(matrix_from_rpy(rpy_rad), xyz)


class SensorGeometry:
    """Mounts and provenance of a recording's sensors (a base of `SourceRecording`)."""

    source: Source
    options: Any
    roles: Roles
    _types: dict[str, str]
    _mounts: dict[str, np.ndarray] | None
    _provenance: dict[str, Any]

    def _warn(self, message: str) -> None:
        raise NotImplementedError

    def tf_tree(self, dynamic: bool = False) -> TfTree:
        raise NotImplementedError

    def navigation(self) -> PoseTrack:
        raise NotImplementedError

    def mountings(self) -> dict[str, np.ndarray]:
        """T_base_sonar per sonar: config where set, else the recording's tf tree by the
        sonar messages' frame_id, else the project default (with a warning)."""
        if self._mounts is None:
            self._mounts = {}
            for s in SONARS:
                topic = self.roles.sonar.get(s)
                if topic is None and self.roles.sonar:
                    continue  # `convert` of a single sonar: no mount (or warning) for the other
                frame = self._frame_of(topic) if topic else ""
                T, role = self._mount(
                    s,
                    frame or FRAME_SONAR[s],
                    getattr(self.options, f"{s}_mount_xyz_m"),
                    getattr(self.options, f"{s}_mount_rpy_deg"),
                    DEFAULT_SONAR_MOUNTS[s],
                )
                self._mounts[s] = T
                self._provenance[f"{s}_sonar"] = {**self._role(topic), **role}
        return dict(self._mounts)

    def provenance(self) -> dict[str, Any]:
        """Per role (each sonar, navigation, DVL, IMU, depth, ground truth): topic, type,
        frame and where each value came from ("recording", "config" or "default")."""
        self.mountings()
        self.navigation()
        out = dict(self._provenance)
        if self.roles.ground_truth is not None:
            out["ground_truth"] = self._role(self.roles.ground_truth)
        return out

    def _role(self, topic: str | None) -> dict[str, Any]:
        return {"topic": topic, "type": self._types.get(topic or "")}

    def _frame_of(self, topic: str) -> str:
        """header.frame_id of the topic's first message ("" when it has none)."""
        times = self.source.times(topic)
        if len(times) == 0:
            return ""
        for _, _, msg in self.source.messages([topic], {int(times[0])}):
            return message_frame(msg)
        return ""

    def _mount(
        self,
        name: str,
        frame: str,
        xyz: Sequence[float] | None,
        rpy_deg: Sequence[float] | None,
        default: tuple[tuple[float, float, float], tuple[float, float, float]],
        parts: tuple[str, ...] = ("xyz", "rpy"),
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """(T_base_sensor, provenance) of one sensor: config overrides the recording's tf
        tree; a part neither gives is the default, with a warning."""
        base = normalise_frame(self.options.base_frame)
        found = (np.eye(4), [base]) if frame == base else self.tf_tree().lookup(base, frame)
        if found is None and self.roles.tf is not None:
            found = self.tf_tree(dynamic=True).lookup(base, frame)
            moving = self.tf_tree().changing_on(found[1]) if found is not None else []
            if moving:
                self._warn(
                    f"{self.source.path}: {self.roles.tf}: the transform "
                    f"{' and '.join(f'{a}->{b}' for a, b in moving[:2])} of {name}'s frame "
                    f"{frame!r} changes during the recording; its first value is used as a "
                    "fixed mount"
                )
        info: dict[str, Any] = {"frame": frame}
        if found is not None:
            info["tf_chain"] = found[1]
        recorded = None if found is None else found[0]
        sources = {
            part: "config" if value is not None else "recording" if found else "default"
            for part, value in (("xyz", xyz), ("rpy", rpy_deg))
            if part in parts
        }
        if xyz is None and rpy_deg is None and recorded is not None:
            T = recorded  # exactly the recording's transform
        else:
            xyz_m = xyz if xyz is not None else (default[0] if recorded is None else None)
            rpy = rpy_deg if rpy_deg is not None else (default[1] if recorded is None else None)
            T = mounting_matrix(
                xyz_m if xyz_m is not None else (0.0, 0.0, 0.0),
                np.deg2rad(rpy if rpy is not None else (0.0, 0.0, 0.0)),
            )
            if recorded is not None and rpy is None:
                T[:3, :3] = recorded[:3, :3]
            if recorded is not None and xyz_m is None:
                T[:3, 3] = recorded[:3, 3]
        info.update({f"mount_{p}": v for p, v in sources.items()})
        defaulted = [p for p, v in sources.items() if v == "default"]
        if defaulted:
            known = ", ".join(self.tf_tree().frames[:6]) or "none"
            self._warn(
                f"{self.source.path}: {name}: frame {frame!r} is not connected to "
                f"{base!r} in the recording's tf tree (frames: {known}); using the default "
                f"mount ({' and '.join(defaulted)}: xyz {list(default[0])} m, "
                f"rpy {list(default[1])} deg); set "
                + " / ".join(f"keyframes.{name}_mount_{p}{_UNIT[p]}" for p in parts)
            )
        overridden = [p for p, v in sources.items() if v == "config"]
        if overridden and found is not None:
            self._warn(
                f"{self.source.path}: {name}: "
                + " and ".join(f"keyframes.{name}_mount_{p}{_UNIT[p]}" for p in overridden)
                + (" overrides" if len(overridden) == 1 else " override")
                + f" the recording's mount of frame {frame!r}"
            )
        return T, info
