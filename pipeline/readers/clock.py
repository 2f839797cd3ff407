"""Recorder clocks that run backwards or jump: found per topic, in the order recorded.

A topic's messages are stored in the order they arrived; their log times should not
decrease along it. A clock that is reset (NTP step, a PC clock set back) stores later
messages with earlier times; sorted by time they interleave with the first run and a
track zig-zags between two places. Such messages (more than `BACKWARDS_TOLERANCE_NS`
behind the latest time before them) are dropped, counted and named in a warning; a
recorder's own jitter (a few ms between threads) is within the tolerance and is sorted.
Where fewer messages are lost by dropping the stray times *ahead* of later ones instead (a
sample stamped an hour late), those are dropped (`backwards`).

Forward jumps (a gap far longer than the topic's usual interval) lose nothing, but
anything interpolated across one is a guess: they are counted and warned.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.readers.source_types import TopicInfo

__all__ = [
    "BACKWARDS_TOLERANCE_NS",
    "GAP_FACTOR",
    "LAST_STAMP_NS",
    "MIN_GAP_NS",
    "Backwards",
    "backwards",
    "check_stamp_range",
    "gap_warning",
]

BACKWARDS_TOLERANCE_NS = 100_000_000
"""A message this far behind an earlier one of its topic [ns] is a clock set back, not
the jitter of a recorder's threads (milliseconds)."""

GAP_FACTOR = 20.0
"""A gap longer than this many of the topic's median intervals is a jump ..."""

MIN_GAP_NS = 1_000_000_000
"""... when it is also at least this long [ns] (a 1 Hz topic missing a sample is not)."""


LAST_STAMP_NS = (2**31 - 1) * 1_000_000_000
"""2038-01-19 03:14:07 UTC: the last second a ROS 2 header stamp (int32 seconds) holds, so
the last a keyframes artifact's frames can carry. A recording dated later is taken as a
recorder whose clock is wrong, not mapped with its times cut."""


@dataclass(frozen=True)
class Backwards:
    """Messages of one topic out of time order (file order), those dropped.

    Attributes:
        behind: (n,) bool, True for each message dropped, in the order given.
        first_t_ns: log time of the first one dropped.
        back_ns: how far it is behind the latest time before it (or, `ahead`, ahead of
            the earliest time after it).
        ahead: the dropped ones are times ahead of the messages recorded after them (a
            few stray times), not times behind the ones before them (a clock set back).
    """

    behind: np.ndarray
    first_t_ns: int
    back_ns: int
    ahead: bool = False

    def warning(self, where: str) -> str:
        n, total = int(self.behind.sum()), len(self.behind)
        first = (
            f"t_ns={self.first_t_ns}"
            if self.first_t_ns >= 0
            else f"t_ns={self.first_t_ns + 2**64}, past 2^63"  # a uint64 time read as int64
        )
        if self.ahead:
            return (
                f"{where}: the clock runs backwards: dropped {n} of {total} messages recorded "
                f"with a time ahead of later ones (first at {first}, "
                f"{self.back_ns * 1e-9:.4g} s ahead)"
            )
        return (
            f"{where}: the clock runs backwards: dropped {n} of {total} messages recorded "
            f"after a later time (first at {first}, "
            f"{self.back_ns * 1e-9:.4g} s back)"
        )


def backwards(t_file_order: np.ndarray, tol_ns: int = BACKWARDS_TOLERANCE_NS) -> Backwards | None:
    """The messages to drop so that the rest are in time order (within `tol_ns`), or None
    when the clock never runs back that far.

    Two readings each leave the rest in order: drop the messages more than `tol_ns` behind
    the latest time before them (a clock set back: what comes after the step), or those
    more than `tol_ns` ahead of the earliest time after them (a few stray times ahead:
    one sample stamped an hour late would otherwise take every later one with it). The
    one that drops fewer is taken; the first on a tie.
    """
    t = np.asarray(t_file_order, np.int64)
    if len(t) < 2:
        return None
    latest = np.maximum.accumulate(t)
    # Compare with the latest time *before* each message (the first has none) ...
    before = np.r_[t[0], latest[:-1]]
    behind = (before - t) > tol_ns
    if not behind.any():
        return None
    # ... or with the earliest time *after* it (the last has none).
    earliest = np.minimum.accumulate(t[::-1])[::-1]
    after = np.r_[earliest[1:], t[-1]]
    ahead = (t - after) > tol_ns
    if ahead.sum() < behind.sum():
        k = int(np.flatnonzero(ahead)[0])
        return Backwards(ahead, int(t[k]), int(t[k] - after[k]), ahead=True)
    k = int(np.flatnonzero(behind)[0])
    return Backwards(behind, int(t[k]), int(before[k] - t[k]))


def _jumps(t: np.ndarray) -> tuple[np.ndarray, float]:
    """(J,) indices k of the jumps forward t[k] -> t[k + 1] of an ascending series, and
    the interval over which one counts as a jump [ns]."""
    dt = np.diff(t)
    limit = max(float(np.median(dt)) * GAP_FACTOR, MIN_GAP_NS)
    return np.flatnonzero(dt > limit), limit


def gap_warning(
    where: str,
    t_sorted: np.ndarray,
    what: str,
    consequence: str | None = None,
    pings_ns: np.ndarray | None = None,
) -> str | None:
    """A warning for jumps forward in an ascending time series (None when there are
    none): count, the largest and where it starts, then `consequence` (by default that
    `what` across a jump is interpolated). With `pings_ns` (the horizontal sonar's ping
    times, for the navigation), how many pings fall inside a jump and are so posed: a
    sonar whose clock did not jump with the navigation's keeps pinging through it."""
    t = np.asarray(t_sorted, np.int64)
    if len(t) < 3:
        return None
    big, limit = _jumps(t)
    if len(big) == 0:
        return None
    k = int(big[np.argmax(t[big + 1] - t[big])])
    line = (
        f"{where}: the clock jumps forward {len(big)} time(s) (largest "
        f"{(t[k + 1] - t[k]) * 1e-9:.4g} s after t_ns={int(t[k])}, over {limit * 1e-9:.3g} s); "
        + (consequence or f"{what} across a jump is interpolated")
    )
    if pings_ns is not None and len(pings_ns):
        lo = np.searchsorted(pings_ns, t[big], side="right")
        hi = np.searchsorted(pings_ns, t[big + 1], side="left")
        inside = int(np.maximum(hi - lo, 0).sum())
        if inside:
            line += (
                f": {inside} of {len(pings_ns)} horizontal pings fall inside one and are posed"
                " as if the vehicle moved straight and steadily across it (a sonar whose clock"
                " did not jump with the navigation's?)"
            )
    return line


def check_stamp_range(path: object, topics: Iterable[TopicInfo], used: Iterable[str]) -> None:
    """A SourceError (one line) naming the first of the `used` topics with a log time past
    `LAST_STAMP_NS`; topics the map does not read are not checked."""
    wanted = set(used)
    for info in topics:
        if info.topic not in wanted or info.first_ns is None or info.last_ns is None:
            continue
        if info.first_ns < 0:  # a uint64 time past 2^63 read into int64
            raise SourceError(
                f"{path}: {info.topic}: a log time is past 2^63 ns (read as "
                f"t_ns={info.first_ns}); the recorder's clock was set wrong"
            )
        if info.last_ns > LAST_STAMP_NS:
            raise SourceError(
                f"{path}: {info.topic}: log time t_ns={info.last_ns} is after 2038-01-19 "
                "03:14:07 UTC, past what a ROS 2 header stamp holds (int32 seconds); the "
                "recorder's clock was set wrong"
            )
