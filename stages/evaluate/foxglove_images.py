"""Keyframe sonar images as Foxglove fan images: each polar (range, angle) image drawn
in Cartesian pixels as the sonar sees it, sensor at the bottom centre, range up."""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from sonarmap.schemas.sonar import KeyframeImages, SonarPing
from sonarmap.stages.evaluate.foxglove_scene import SceneMessage, foxglove_messages, timestamp

__all__ = ["FAN_HEIGHT_PX", "fan_image", "fan_lookup", "fan_messages"]

FAN_HEIGHT_PX = 256
"""Rows of a fan image: the sonar's maximum range spans them."""


def fan_lookup(
    ranges_m: np.ndarray, angles_rad: np.ndarray, height_px: int = FAN_HEIGHT_PX
) -> tuple[np.ndarray, tuple[int, int]]:
    """Where each fan pixel reads the polar image: (height * width,) flat index into the
    (n_ranges, n_beams) image, -1 outside the fan (nearest bin), and the fan's shape.
    Sensor at the bottom centre, range up, positive angles to the left."""
    ranges = np.asarray(ranges_m, np.float64)
    angles = np.asarray(angles_rad, np.float64)
    r_max = float(ranges[-1]) if ranges.size else 1.0
    res = r_max / max(height_px - 1, 1)
    half = float(np.max(np.abs(angles))) if angles.size else 0.0
    half_w = int(np.ceil(r_max * np.sin(min(half, np.pi / 2)) / res))
    cols = np.arange(-half_w, half_w + 1, dtype=np.float64) * res
    rows = (height_px - 1 - np.arange(height_px, dtype=np.float64)) * res
    fwd, left = np.meshgrid(rows, -cols, indexing="ij")
    r = np.hypot(fwd, left)
    a = np.arctan2(left, fwd)
    ri = np.clip(np.searchsorted(ranges, r), 1, max(len(ranges) - 1, 1))
    ri = np.where(np.abs(ranges[ri - 1] - r) <= np.abs(ranges[ri] - r), ri - 1, ri)
    ai = np.clip(np.searchsorted(angles, a), 1, max(len(angles) - 1, 1))
    ai = np.where(np.abs(angles[ai - 1] - a) <= np.abs(angles[ai] - a), ai - 1, ai)
    step = float(np.median(np.diff(angles))) if len(angles) > 1 else 0.0
    inside = (r >= ranges[0]) & (r <= r_max) & (a >= angles[0] - step) & (a <= angles[-1] + step)
    flat = np.where(inside, ri * len(angles) + ai, -1).reshape(-1)
    return flat, (height_px, len(cols))


def fan_image(ping: SonarPing, height_px: int = FAN_HEIGHT_PX) -> np.ndarray:
    """(height, width) uint8: the polar image drawn as its fan (`fan_lookup`), 0 outside."""
    flat, shape = fan_lookup(ping.ranges_m, ping.angles_rad, height_px)
    return _draw(np.asarray(ping.image, np.uint8), flat, shape)


def _draw(image: np.ndarray, flat: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    padded = np.append(image.reshape(-1), np.uint8(0))  # index -1 reads the 0 appended
    return padded[flat].reshape(shape)


def fan_messages(frames: Iterable[KeyframeImages]) -> Iterator[SceneMessage]:
    """Each keyframe's horizontal and vertical image as a mono8 fan at its ping time,
    made as the frames are read (a keyframe's two in time order)."""
    fm = foxglove_messages()
    # a sonar's bins rarely change over a mission: one lookup per distinct geometry
    lookups: dict[tuple[bytes, bytes], tuple[np.ndarray, tuple[int, int]]] = {}
    for kf in frames:
        pair = (("horizontal", kf.horizontal), ("vertical", kf.vertical))
        for sonar, ping in sorted(pair, key=lambda p: (p[1].t_ns, p[0] == "vertical")):
            geometry = (np.asarray(ping.ranges_m).tobytes(), np.asarray(ping.angles_rad).tobytes())
            if geometry not in lookups:
                lookups[geometry] = fan_lookup(ping.ranges_m, ping.angles_rad)
            img = _draw(np.asarray(ping.image, np.uint8), *lookups[geometry])
            msg = fm.RawImage(
                timestamp=timestamp(ping.t_ns),
                frame_id=f"sonar_{sonar}",
                width=img.shape[1],
                height=img.shape[0],
                encoding="mono8",
                step=img.shape[1],
                data=img.tobytes(),
            )
            yield SceneMessage(f"/sonar/{sonar}/fan", msg, int(ping.t_ns))
