"""The `Sensors` record: the sonar pair's mountings and what the recording carries.

The keyframes stage writes it as `sensors.json`; the engine reads that file once per
stage that takes the `keyframes.sensors` input and hands the stage a `Sensors`, so no
stage looks into nested dicts. The file's bytes are the keyframes stage's dict as written;
`to_json` gives the same dict back.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Literal

import numpy as np

__all__ = ["SONAR_ROLES", "Sensors", "SonarMount", "SonarRole"]

SonarRole = Literal["horizontal", "vertical"]
SONAR_ROLES: tuple[SonarRole, ...] = ("horizontal", "vertical")

_RIGID_ATOL = 1e-6
"""How far R R^T may be from I for a mounting to count as a rotation (rounded JSON)."""


@dataclass(frozen=True)
class SonarMount:
    """Where one sonar sits on the vehicle.

    Attributes:
        T_base_sonar: (4, 4) float64 read-only rigid transform, sonar frame -> base_link.
        details: the rest of the sonar's entry as written (its fan `fov_deg`, range
            window, vertical aperture, beam summary and where they came from).
    """

    T_base_sonar: np.ndarray
    details: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))

    def _number(self, key: str) -> float | None:
        value = self.details.get(key)
        return (
            float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None
        )

    @property
    def fov_deg(self) -> float | None:
        """The sonar's fan [deg] as the keyframes stage found it (None: not recorded)."""
        return self._number("fov_deg")

    @property
    def max_range_m(self) -> float | None:
        """The far end of the sonar's range window [m] (None: not recorded)."""
        return self._number("max_range_m")

    @property
    def min_range_m(self) -> float | None:
        """The near end of the sonar's range window [m] (None: not recorded)."""
        return self._number("min_range_m")

    @property
    def vertical_aperture_deg(self) -> float | None:
        """The sonar's aperture across its fan [deg] (None: not recorded)."""
        return self._number("vertical_aperture_deg")

    @classmethod
    def from_json(cls, role: str, doc: Any) -> SonarMount:
        """Read `{"T_base_sonar": 4x4 nested list}`; a ValueError names the field."""
        where = f"{role}.T_base_sonar"
        if not isinstance(doc, Mapping) or "T_base_sonar" not in doc:
            raise ValueError(f"sensors has no {where}")
        try:
            m = np.array(doc["T_base_sonar"], dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise ValueError(f"sensors.{where} is not a 4x4 matrix of numbers") from err
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise ValueError(f"sensors.{where} is not a 4x4 matrix of finite numbers")
        rotation = m[:3, :3]
        rigid = np.allclose(rotation @ rotation.T, np.eye(3), atol=_RIGID_ATOL)
        if not rigid or not np.allclose(m[3], (0.0, 0.0, 0.0, 1.0)):
            raise ValueError(f"sensors.{where} is not a 4x4 rigid transform")
        m.setflags(write=False)
        rest = {k: v for k, v in doc.items() if k != "T_base_sonar"}
        return cls(m, MappingProxyType(rest))


def _frozen(doc: Any, name: str) -> Mapping[str, Any]:
    if doc is None:
        return MappingProxyType({})
    if not isinstance(doc, Mapping):
        raise ValueError(f"sensors.{name} is not a mapping")
    return MappingProxyType(dict(doc))


@dataclass(frozen=True)
class Sensors:
    """What `sensors.json` holds: each sonar's mounting and facts about the recording.

    Attributes:
        sonars: role ("horizontal", "vertical") -> its mounting; a role may be absent
            only in hand-made inputs read by `of` (`sonar` then raises).
        has_ground_truth: the recording carries true poses (a simulation).
        has_labels: its sonar images carry per-pixel class labels.
        source: the reader's description of the recording (format, topics, warnings; no file name).
        pairing: counts of the ping pairing (pings, pairs, unpaired, keyframes).
        extra: the file's other entries as written (e.g. `provenance`: where each role's
            topic, frame and mount came from).
    """

    sonars: Mapping[str, SonarMount]
    has_ground_truth: bool = False
    has_labels: bool = False
    source: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    pairing: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    extra: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))

    def sonar(self, role: SonarRole) -> SonarMount:
        """The mounting of sonar `role`; ValueError when the record has none."""
        mount = self.sonars.get(role)
        if mount is None:
            raise ValueError(f"sensors has no {role}.T_base_sonar")
        return mount

    @property
    def horizontal(self) -> SonarMount:
        return self.sonar("horizontal")

    @property
    def vertical(self) -> SonarMount:
        return self.sonar("vertical")

    @property
    def T_h_v(self) -> np.ndarray:
        """(4, 4) the vertical sonar's pose in the horizontal sonar's frame."""
        return np.linalg.inv(self.horizontal.T_base_sonar) @ self.vertical.T_base_sonar

    @classmethod
    def from_json(cls, doc: Any, *, partial: bool = False) -> Sensors:
        """Read the dict of `sensors.json`; a ValueError names the bad field. Both
        sonars must be there unless `partial`."""
        if not isinstance(doc, Mapping):
            raise ValueError("sensors is not a JSON object")
        roles = [r for r in SONAR_ROLES if r in doc or not partial]
        sonars: dict[str, SonarMount] = {r: SonarMount.from_json(r, doc.get(r)) for r in roles}
        flags = {}
        for name in ("has_ground_truth", "has_labels"):
            value = doc.get(name, False)
            if not isinstance(value, bool):
                raise ValueError(f"sensors.{name} is not true or false")
            flags[name] = value
        known = {*SONAR_ROLES, "has_ground_truth", "has_labels", "source", "pairing"}
        return cls(
            MappingProxyType(sonars),
            source=_frozen(doc.get("source"), "source"),
            pairing=_frozen(doc.get("pairing"), "pairing"),
            extra=MappingProxyType({k: v for k, v in doc.items() if k not in known}),
            **flags,
        )

    @classmethod
    def of(cls, value: Sensors | Mapping[str, Any]) -> Sensors:
        """`value` itself, or the record read from a `sensors.json` dict, a sonar missing
        only when it is asked for (a stage's `run` called directly, as tests do, gets
        the dict)."""
        return value if isinstance(value, Sensors) else cls.from_json(value, partial=True)

    def to_json(self) -> dict[str, Any]:
        """The dict `sensors.json` holds (the keyframes stage's, key for key)."""
        doc: dict[str, Any] = {
            role: {"T_base_sonar": mount.T_base_sonar.tolist(), **mount.details}
            for role, mount in self.sonars.items()
        }
        doc.update(
            has_ground_truth=self.has_ground_truth,
            has_labels=self.has_labels,
            source=dict(self.source),
            pairing=dict(self.pairing),
            **self.extra,
        )
        return doc
