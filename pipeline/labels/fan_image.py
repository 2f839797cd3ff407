"""A horizontal ping as a Cartesian fan image, and the map between its pixels and metres.

Annotation tools draw on ordinary images. The image here is the fan seen from above,
forward up and left on the left: pixel column u grows towards the vehicle's right (-y)
and pixel row v grows backwards (-x). Pixel coordinates are COCO's: continuous, (0, 0)
at the top-left corner of the top-left pixel, so pixel (i, j) covers [i, i+1) x [j, j+1)
and its centre is (i + 0.5, j + 0.5).

    u = (y_left_m - y) / pixel_m        v = (x_top_m - x) / pixel_m

with x forward, y left [m] in the horizontal sonar's fan plane (REP 103; paper Eq. 1
with phi = 0), the frame of `sonarmap.schemas.annotations`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from sonarmap.schemas.sonar import SonarPing

__all__ = [
    "MAX_PIXELS",
    "FanGeometry",
    "ImageTooLarge",
    "fan_geometry",
    "fan_image",
    "metres_to_pixels",
    "pixels_to_metres",
]

MAX_SIDE_PX = 2048
"""Largest image side: the pixel grows for a long-range sonar rather than the image."""

MAX_PIXELS = MAX_SIDE_PX * MAX_SIDE_PX
"""Most pixels in an image drawn (a given pixel side included): `fan_image` holds about
90 bytes per pixel while drawing, so some 380 MB at this size."""


class ImageTooLarge(ValueError):
    """A pixel side that would make an image of more than `MAX_PIXELS`."""


DISPLAY_PERCENTILE = 99.5
"""Intensities are stretched so this percentile of the fan's cells is white: simulated
and many real images use a small part of 0-255, too dark to label by eye."""

DISPLAY_MIN_SHARE = 0.25
"""...but white is never below this share of the brightest cell: in an image that is
almost all background, the percentile is the noise, which would turn white."""


@dataclass(frozen=True)
class FanGeometry:
    """How one exported image's pixels map to the sonar frame (see the module docstring)."""

    width_px: int
    height_px: int
    pixel_m: float
    x_top_m: float
    y_left_m: float

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def _edges(centres: np.ndarray) -> np.ndarray:
    """Bin edges halfway between ascending centres (the outer ones mirrored)."""
    c = np.asarray(centres, np.float64)
    if len(c) == 1:
        return np.array([c[0] - 0.5, c[0] + 0.5])
    mid = (c[1:] + c[:-1]) / 2
    return np.concatenate([[2 * c[0] - mid[0]], mid, [2 * c[-1] - mid[-1]]])


def fan_geometry(ping: SonarPing, pixel_m: float | None = None) -> FanGeometry:
    """The image grid that holds a ping's whole fan.

    Args:
        ping: a horizontal ping (ranges ascending, bearings ascending, positive left).
        pixel_m: pixel side [m]; None: the ping's range resolution, enlarged if the image
            would exceed MAX_SIDE_PX.
    """
    r_edges = _edges(ping.ranges_m)
    a_edges = _edges(ping.angles_rad)
    r_max = float(r_edges[-1])
    # The fan's extent: its outer arc (sampled finely) and the sonar's own position.
    arc = np.linspace(a_edges[0], a_edges[-1], 721)
    x = np.concatenate([[0.0], r_max * np.cos(arc)])
    y = np.concatenate([[0.0], r_max * np.sin(arc)])
    x_top, x_bottom, y_left, y_right = x.max(), x.min(), y.max(), y.min()
    if pixel_m is None:
        pixel_m = max(ping.range_resolution_m, 1e-3)
        pixel_m = max(pixel_m, (x_top - x_bottom) / MAX_SIDE_PX, (y_left - y_right) / MAX_SIDE_PX)
    width = max(1, math.ceil((y_left - y_right) / pixel_m))
    height = max(1, math.ceil((x_top - x_bottom) / pixel_m))
    if width * height > MAX_PIXELS:
        smallest = math.sqrt((y_left - y_right) * (x_top - x_bottom) / MAX_PIXELS)
        raise ImageTooLarge(
            f"a pixel of {pixel_m:g} m makes a {width} x {height} image of this fan "
            f"({width * height * 90 / 2**30:.3g} GiB while drawn; at most {MAX_PIXELS} pixels): "
            f"use {math.ceil(smallest * 1e4) / 1e4:g} m or more"
        )
    return FanGeometry(width, height, float(pixel_m), float(x_top), float(y_left))


def pixels_to_metres(uv: np.ndarray, g: FanGeometry) -> np.ndarray:
    """(n, 2) COCO pixel coordinates (u, v) -> (n, 2) fan-plane (x, y) [m]."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    return np.stack([g.x_top_m - uv[:, 1] * g.pixel_m, g.y_left_m - uv[:, 0] * g.pixel_m], axis=1)


def metres_to_pixels(xy: np.ndarray, g: FanGeometry) -> np.ndarray:
    """(n, 2) fan-plane (x, y) [m] -> (n, 2) COCO pixel coordinates (u, v)."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    return np.stack([(g.y_left_m - xy[:, 1]) / g.pixel_m, (g.x_top_m - xy[:, 0]) / g.pixel_m], 1)


def fan_image(ping: SonarPing, g: FanGeometry) -> np.ndarray:
    """(height, width) uint8 image of a ping on the grid `g`: each pixel shows the polar
    cell its centre falls in (nearest range bin, the beam whose angular bin holds it, so an
    uneven beam table is drawn as it is); outside the fan, 0."""
    u = np.arange(g.width_px) + 0.5
    v = np.arange(g.height_px) + 0.5
    uu, vv = np.meshgrid(u, v)
    xy = pixels_to_metres(np.stack([uu.ravel(), vv.ravel()], 1), g)
    r = np.hypot(xy[:, 0], xy[:, 1])
    a = np.arctan2(xy[:, 1], xy[:, 0])
    r_edges, a_edges = _edges(ping.ranges_m), _edges(ping.angles_rad)
    ri = np.searchsorted(r_edges, r, side="right") - 1
    ai = np.searchsorted(a_edges, a, side="right") - 1
    inside = (ri >= 0) & (ri < len(ping.ranges_m)) & (ai >= 0) & (ai < len(ping.angles_rad))
    image = np.asarray(ping.image)
    top = 0.0
    if image.size:
        top = max(float(np.percentile(image, DISPLAY_PERCENTILE)), DISPLAY_MIN_SHARE * image.max())
    scale = 255.0 / top if top > 0 else 1.0
    values = np.zeros(len(r), np.float64)
    values[inside] = image[ri[inside], ai[inside]].astype(np.float64) * scale
    return np.clip(np.rint(values), 0, 255).astype(np.uint8).reshape(g.height_px, g.width_px)
