"""Log times against header stamps: a sonar whose recorder clock runs apart from the
navigation's.

sonarmap times every message by its log time (when the recorder stored it). A driver's
header stamp says when the sensor measured; the two differ by a transport delay that is
about the same for every topic of one recorder. Where a sonar's log times sit seconds from
its stamps while the navigation's do not (a second computer whose clock is off, a driver
that buffers), its pings are posed that far along the track, and nothing else in the
recording shows it. The navigation's offset is the median over its messages (all are read);
a sonar's is that of the first keyframe's ping (stage `keyframes` decodes it in every run),
so the check reads nothing more and does not depend on what is cached.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["median_offset_s", "stamp_ns"]


def stamp_ns(message: Any) -> int | None:
    """A decoded message's header stamp [ns]; None when it has none or it is unset (0)."""
    direct = getattr(message, "stamp_ns", None)  # the fast ProjectedSonarImage decoder's
    if isinstance(direct, int | np.integer):
        return int(direct) or None
    stamp = getattr(getattr(message, "header", None), "stamp", None)
    sec, nsec = getattr(stamp, "sec", None), getattr(stamp, "nanosec", None)
    if not isinstance(sec, int | np.integer) or not isinstance(nsec, int | np.integer):
        return None
    return int(sec) * 1_000_000_000 + int(nsec) or None


def median_offset_s(offsets_ns: Sequence[int]) -> float | None:
    """Median of (log time - header stamp) [s], rounded to the microsecond; None: none."""
    return round(float(np.median(offsets_ns)) * 1e-9, 6) if len(offsets_ns) else None
