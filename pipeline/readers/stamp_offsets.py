"""Log times against header stamps: a sonar whose recorder clock runs apart from the
navigation's.

sonarmap times every message by its log time (when the recorder stored it). A driver's
header stamp says when the sensor measured; the two differ by a transport delay that is
about the same for every topic of one recorder. Where one sonar's log times sit seconds
from its stamps while the navigation's do not (a second computer whose clock is off, a
driver that buffers), its pings are posed that far along the track, and nothing else in
the recording shows it. Checked on a sample of each topic's messages.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from sonarmap.pipeline.readers.source_types import Source

__all__ = ["OFFSET_WARN_S", "SAMPLE", "stamp_offset_warnings"]

SAMPLE = 15
"""Messages read per topic, evenly spread over it."""

OFFSET_WARN_S = 0.25
"""Warn when a sonar's median (log time - stamp) differs from the navigation's by more than
this [s]: at the 0.5 m/s of a survey, a ping posed 0.125 m along the track, more than a
voxel of the map (0.1 m)."""


def _stamp_ns(message: Any) -> int | None:
    """header.stamp in ns, None when the message has none or it is unset (0)."""
    direct = getattr(message, "stamp_ns", None)  # the fast ProjectedSonarImage decoder's
    if isinstance(direct, int | np.integer):
        return int(direct) or None
    stamp = getattr(getattr(message, "header", None), "stamp", None)
    if stamp is None:
        return None
    sec, nsec = getattr(stamp, "sec", None), getattr(stamp, "nanosec", None)
    if not isinstance(sec, int | np.integer) or not isinstance(nsec, int | np.integer):
        return None
    value = int(sec) * 1_000_000_000 + int(nsec)
    return value or None


def median_offset_s(source: Source, topic: str) -> float | None:
    """Median of (log time - header stamp) [s] over up to `SAMPLE` of the topic's
    messages; None when none carries a stamp."""
    times = source.times(topic)
    if len(times) == 0:
        return None
    picked = times[np.unique(np.linspace(0, len(times) - 1, SAMPLE).round().astype(np.int64))]
    offsets = [
        t - stamp
        for _, t, message in source.messages([topic], set(picked.tolist()))
        if (stamp := _stamp_ns(message)) is not None
    ]
    return float(np.median(offsets)) * 1e-9 if offsets else None


def stamp_offset_warnings(
    source: Source, sonar_topics: Iterable[str], navigation: str | None
) -> list[str]:
    """One warning per sonar topic whose log-time offset from its stamps differs from the
    navigation topic's by more than `OFFSET_WARN_S`."""
    if navigation is None:
        return []
    nav = median_offset_s(source, navigation)
    if nav is None:
        return []
    out = []
    for topic in sonar_topics:
        own = median_offset_s(source, topic)
        if own is None or abs(own - nav) <= OFFSET_WARN_S:
            continue
        out.append(
            f"{source.path}: {topic}: its log times are {own:+.3g} s from its header stamps, "
            f"{navigation}'s {nav:+.3g} s: pings are posed by log time, so if the stamps are "
            f"right they are posed {abs(own - nav):.3g} s along the track from where they "
            "were taken (the recorders' clocks differ?)"
        )
    return out
