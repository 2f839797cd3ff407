"""Which topic plays which role: sonars, their label/truth images, navigation, truth.

Topics are found by message type when that is unambiguous; config keys
(`keyframes.horizontal_topic`, ...) decide otherwise. Every failure is one line naming
the file, the topics found and the key to set.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.readers.depth import FLUID_PRESSURE_TYPE
from sonarmap.pipeline.readers.dvl import TWIST_TYPES, is_dvl_type
from sonarmap.pipeline.readers.navigation import NAV_TYPES
from sonarmap.pipeline.readers.sonar_decode import IMAGE_SONAR_TYPES, SONAR_TYPES
from sonarmap.pipeline.readers.source_types import TopicInfo
from sonarmap.schemas.topics import (
    SONARS,
    TOPIC_DEAD_RECKONING,
    TOPIC_GROUND_TRUTH,
    TOPIC_TF_STATIC,
)

__all__ = ["Roles", "detect_roles", "topic_listing"]

_HINTS = {
    "horizontal": ("horizontal", "horiz", "m750d"),
    "vertical": ("vertical", "vert", "m1200d"),
}
_GT_HINTS = ("ground_truth", "groundtruth", "gt_")
_DEPTH_HINTS = ("depth", "pressure", "bar30", "baro")
"""A pose topic named like a depth sensor's (/bar30/pose, /depth) is not navigation
when a DVL and an IMU can dead-reckon."""
IMU_TYPE = "sensor_msgs/msg/Imu"
TF_TYPE = "tf2_msgs/msg/TFMessage"


@dataclass
class Roles:
    """Topic per role (None/absent when the recording has none)."""

    sonar: dict[str, str] = field(default_factory=dict)
    labels: dict[str, str] = field(default_factory=dict)
    truth_angle: dict[str, str] = field(default_factory=dict)
    navigation: str | None = None
    ground_truth: str | None = None
    dvl: str | None = None
    imu: str | None = None
    depth: str | None = None
    tf_static: str | None = None
    tf: str | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-able {role: topic}."""
        out: dict[str, Any] = {f"{s}_sonar": t for s, t in self.sonar.items()}
        out.update({f"{s}_labels": t for s, t in self.labels.items()})
        out.update({f"{s}_truth_angle": t for s, t in self.truth_angle.items()})
        for key in ("navigation", "ground_truth", "dvl", "imu", "depth", "tf_static", "tf"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        return out


_LISTING_CHARS = 200
"""A listing of topics in an error line stops here (the line stays within 400 characters)."""


def topic_listing(topics: Sequence[TopicInfo]) -> str:
    """'/a [type], /b [type]' or 'none'; when that is long, the names alone, cut after
    `_LISTING_CHARS` with the count left."""
    typed = ", ".join(f"{t.topic} [{t.msgtype}]" for t in topics)
    if len(typed) <= _LISTING_CHARS:
        return typed or "none"
    out: list[str] = []
    for k, t in enumerate(topics):
        if out and sum(len(x) + 2 for x in out) + len(t.topic) > _LISTING_CHARS:
            return ", ".join(out) + f", and {len(topics) - k} more"
        out.append(t.topic)
    return ", ".join(out)


def _fail(path: Path, topics: Sequence[TopicInfo], problem: str, key: str) -> SourceError:
    return SourceError(f"{path}: {problem} (topics: {topic_listing(topics)}); set keyframes.{key}")


def _configured(
    path: Path, topics: dict[str, TopicInfo], name: str, allowed: Sequence[str], key: str
) -> str:
    info = topics.get(name)
    if info is None:
        raise _missing(path, topics, key, name, lambda _t, m: m in allowed)
    if info.msgtype not in allowed:
        raise _fail(
            path,
            list(topics.values()),
            f"topic {name} has unsupported type {info.msgtype} (supported: {', '.join(allowed)})",
            key,
        )
    return name


def _sonars(
    path: Path, topics: dict[str, TopicInfo], options: Any, require_pair: bool
) -> dict[str, str]:
    allowed = (*SONAR_TYPES, *IMAGE_SONAR_TYPES)
    chosen = {
        s: _configured(path, topics, getattr(options, f"{s}_topic"), allowed, f"{s}_topic")
        for s in SONARS
        if getattr(options, f"{s}_topic", None)
    }
    candidates = [
        t for t, i in topics.items() if i.msgtype in SONAR_TYPES and t not in chosen.values()
    ]
    listing = list(topics.values())
    if require_pair and len(candidates) + len(chosen) == 1:
        raise _fail(
            path,
            listing,
            "one sonar topic, but sonarmap maps an orthogonal pair (horizontal + vertical)",
            "horizontal_topic and keyframes.vertical_topic",
        )
    if not candidates and not chosen:
        if require_pair:
            raise _fail(
                path,
                listing,
                "no sonar topic found",
                "horizontal_topic and keyframes.vertical_topic",
            )
        return {}
    for s in SONARS:
        if s in chosen:
            continue
        hinted = [c for c in candidates if any(h in c.lower() for h in _HINTS[s])]
        other = [c for c in candidates if c not in hinted]
        if len(hinted) == 1:
            chosen[s] = hinted[0]
        elif len(hinted) > 1:
            raise _fail(
                path, listing, f"{len(hinted)} candidate {s} sonar topics {hinted}", f"{s}_topic"
            )
        elif len(candidates) == 1 and not require_pair and not chosen:
            chosen[s] = candidates[0]
        elif require_pair and other:
            raise _fail(
                path, listing, f"cannot tell which of {other} is the {s} sonar", f"{s}_topic"
            )
        elif require_pair:
            raise _fail(path, listing, f"no {s} sonar topic found", f"{s}_topic")
        candidates = [c for c in candidates if c not in chosen.values()]
    return chosen


def _navigation(
    path: Path, topics: dict[str, TopicInfo], options: Any, roles: Roles, require: bool
) -> None:
    listing = list(topics.values())
    if getattr(options, "ground_truth_topic", None):
        roles.ground_truth = _configured(
            path, topics, options.ground_truth_topic, NAV_TYPES, "ground_truth_topic"
        )
    nav = [t for t, i in topics.items() if i.msgtype in NAV_TYPES]
    if roles.ground_truth is None:
        gt = [t for t in nav if any(h in t.lower() for h in _GT_HINTS)]
        if TOPIC_GROUND_TRUTH in gt or len(gt) == 1:
            roles.ground_truth = TOPIC_GROUND_TRUTH if TOPIC_GROUND_TRUTH in gt else gt[0]
    # A configured depth topic replaces the navigation's z; it must exist either way.
    depth = getattr(options, "depth_topic", None)
    if depth:
        roles.depth = _pick(path, topics, options, "depth_topic", _any_depth)
    if getattr(options, "navigation_topic", None):
        roles.navigation = _configured(
            path, topics, options.navigation_topic, NAV_TYPES, "navigation_topic"
        )
        return
    nav = [t for t in nav if t != roles.ground_truth and not any(h in t.lower() for h in _GT_HINTS)]
    # A depth sensor's pose (only z set, as robot_localization takes depth) is no
    # navigation: with a DVL and an IMU to dead-reckon from, it is the depth.
    depth_poses = [t for t in nav if t == roles.depth or _named_depth(t)]
    if depth_poses and _can_dead_reckon(topics):
        nav = [t for t in nav if t not in depth_poses]
        if not nav and roles.depth is None and len(depth_poses) == 1:
            roles.depth = depth_poses[0]
    if TOPIC_DEAD_RECKONING in nav or len(nav) == 1:
        roles.navigation = TOPIC_DEAD_RECKONING if TOPIC_DEAD_RECKONING in nav else nav[0]
        return
    if len(nav) > 1:
        raise _fail(
            path, listing, f"{len(nav)} candidate navigation topics {nav}", "navigation_topic"
        )
    _dead_reckoning_inputs(path, topics, options, roles)
    if roles.dvl is None and require:
        raise _fail(
            path,
            listing,
            "no navigation topic (Odometry/PoseStamped/PoseWithCovarianceStamped) and no DVL + IMU "
            "for dead reckoning",
            "navigation_topic (or keyframes.dvl_topic and keyframes.imu_topic)",
        )


def _missing(
    path: Path, topics: dict[str, TopicInfo], key: str, name: str, fits: Any
) -> SourceError:
    """A configured topic that is not in the recording: name it and list the candidates."""
    listing = topic_listing([i for t, i in topics.items() if fits(t, i.msgtype)])
    return SourceError(
        f"{path}: configured topic {name} not found (keyframes.{key}; candidates: {listing}; "
        f"{len(topics)} topics in all)"
    )


def _is_dvl(topic: str, msgtype: str) -> bool:
    return is_dvl_type(msgtype) or (msgtype in TWIST_TYPES and "dvl" in topic.lower())


def _is_depth(topic: str, msgtype: str) -> bool:
    return msgtype == FLUID_PRESSURE_TYPE or msgtype.split("/")[-1] == "Depth"


def _is_imu(topic: str, msgtype: str) -> bool:
    return msgtype == IMU_TYPE


def _any_depth(topic: str, msgtype: str) -> bool:
    """Candidates for a configured depth topic: depth/pressure messages and poses."""
    return _is_depth(topic, msgtype) or msgtype in NAV_TYPES


def _pick(
    path: Path, topics: dict[str, TopicInfo], options: Any, key: str, fits: Any
) -> str | None:
    """A role's topic: the configured one (which must exist), else the only candidate."""
    configured = getattr(options, key, None)
    if configured:
        if configured not in topics:
            raise _missing(path, topics, key, str(configured), fits)
        return str(configured)
    found = [t for t, i in topics.items() if fits(t, i.msgtype)]
    if len(found) > 1:
        raise _fail(path, list(topics.values()), f"{len(found)} candidate topics {found}", key)
    return found[0] if found else None


def _named_depth(topic: str) -> bool:
    return any(h in topic.lower() for h in _DEPTH_HINTS)


def _can_dead_reckon(topics: dict[str, TopicInfo]) -> bool:
    return any(_is_dvl(t, i.msgtype) for t, i in topics.items()) and any(
        _is_imu(t, i.msgtype) for t, i in topics.items()
    )


def _dead_reckoning_inputs(
    path: Path, topics: dict[str, TopicInfo], options: Any, roles: Roles
) -> None:
    dvl = _pick(path, topics, options, "dvl_topic", _is_dvl)
    imu = _pick(path, topics, options, "imu_topic", _is_imu)
    if dvl and imu:
        roles.dvl, roles.imu = dvl, imu
        if roles.depth is not None:  # a depth sensor's pose, set aside as navigation
            return
        roles.depth = _pick(
            path,
            topics,
            options,
            "depth_topic",
            _any_depth if getattr(options, "depth_topic", None) else _is_depth,
        )


def detect_roles(
    path: Path, topics: Sequence[TopicInfo], options: Any, *, require_pair: bool = True
) -> Roles:
    """Assign topics to roles.

    Args:
        path: the recording (for messages).
        topics: its topics.
        options: reader options (topic overrides).
        require_pair: keyframes need both sonars and navigation; `convert` does not.

    Raises:
        SourceError: a missing or ambiguous role, a configured topic absent or of the wrong type.
    """
    by_name = {t.topic: t for t in topics}
    roles = Roles(sonar=_sonars(path, by_name, options, require_pair))
    for s, topic in roles.sonar.items():
        for suffix, target in (("labels", roles.labels), ("truth_angle", roles.truth_angle)):
            name = f"{topic}/{suffix}"
            if by_name.get(name) is not None and by_name[name].msgtype == "sensor_msgs/msg/Image":
                target[s] = name
    _navigation(path, by_name, options, roles, require_pair)
    if TOPIC_TF_STATIC in by_name:
        roles.tf_static = TOPIC_TF_STATIC
    if "/tf" in by_name and by_name["/tf"].msgtype == TF_TYPE:
        roles.tf = "/tf"
    return roles
