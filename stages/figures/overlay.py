"""`overlay.png`: one keyframe's objects (classify's `objects.parquet`) drawn over its
horizontal image."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.schemas.objects import UNKNOWN_CLASS_ID
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.kernels.figure_png import png_bytes

__all__ = ["busiest_keyframe", "fan_raster", "overlay_png"]

RASTER_PX = 600
"""Pixels of the longer side of the fan's Cartesian raster in `overlay_png`."""


def fan_raster(
    image: np.ndarray, ranges_m: np.ndarray, angles_rad: np.ndarray, px: int = RASTER_PX
) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """A polar sonar image resampled (nearest range bin and beam) onto a Cartesian grid of
    the fan plane, x = -r sin(a) (right), y = r cos(a) (forward); NaN outside the fan.

    Returns:
        (image (rows, cols) float, extent (left, right, bottom, top) [m] for `imshow`).
    """
    r = np.asarray(ranges_m, np.float64)
    a = np.asarray(angles_rad, np.float64)
    xs, ys = -r[-1] * np.sin(a), r[:, None] * np.cos(a)[None, :]
    left, right = min(float(xs.min()), 0.0), max(float(xs.max()), 0.0)
    bottom, top = min(float(ys.min()), 0.0), float(r[-1])
    cell = max(right - left, top - bottom) / px
    cols = max(1, int(np.ceil((right - left) / cell)))
    rows = max(1, int(np.ceil((top - bottom) / cell)))
    gx = left + (np.arange(cols) + 0.5) * cell
    gy = bottom + (np.arange(rows) + 0.5) * cell
    rr = np.hypot(gx[None, :], gy[:, None])
    aa = np.arctan2(-gx[None, :], gy[:, None])
    # Nearest bin and beam on the (possibly uneven) axes; beams may run either way.
    ri = np.clip(np.searchsorted(r, rr), 1, len(r) - 1)
    ri -= (rr - r[ri - 1]) < (r[ri] - rr)
    order = np.argsort(a)
    sa = a[order]
    bi = np.clip(np.searchsorted(sa, aa), 1, len(sa) - 1)
    bi -= (aa - sa[bi - 1]) < (sa[bi] - aa)
    half_beam = float(np.abs(np.diff(sa)).max()) / 2 if len(sa) > 1 else np.pi
    inside = (rr >= r[0]) & (rr <= r[-1]) & (aa >= sa[0] - half_beam) & (aa <= sa[-1] + half_beam)
    out = np.where(inside, np.asarray(image, np.float64)[ri, order[bi]], np.nan)
    return out, (left, left + cols * cell, bottom, bottom + rows * cell)


def busiest_keyframe(objects: pa.Table) -> tuple[int, pa.Table]:
    """The keyframe with the most accepted objects (the first of equals) and its rows."""
    kf = objects.column("keyframe_id").to_numpy()
    accepted = objects.column("class_id").to_numpy() != UNKNOWN_CLASS_ID
    ids, first, sizes = np.unique(kf, return_index=True, return_counts=True)
    best = int(np.argmax(np.bincount(np.searchsorted(ids, kf[accepted]), minlength=len(ids))))
    return int(ids[best]), objects.slice(int(first[best]), int(sizes[best]))


def overlay_png(
    frame: KeyframeImages, objects: pa.Table, table: ClassTable = DEFAULT_TABLE
) -> bytes:
    """Class-coloured overlay of one keyframe: the horizontal image in fan-plane Cartesian
    coordinates with each object's bounding box and label (class, probability; truth).

    Args:
        frame: the keyframe.
        objects: that keyframe's rows of objects.parquet.

    Returns:
        PNG bytes.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    ping = frame.horizontal
    img, extent = fan_raster(ping.image, ping.ranges_m, ping.angles_rad)
    fig = Figure(figsize=(8, 6), dpi=100)
    ax = fig.add_subplot()
    shown = img[np.isfinite(img)]
    vmin = float(np.percentile(shown, 90)) if shown.size else 0.0
    vmax = max(float(shown.max()) if shown.size else 1.0, 1.0)
    ax.imshow(img, cmap="gray", vmin=vmin, vmax=vmax, extent=extent, origin="lower",
              interpolation="nearest")  # fmt: skip
    cmap = matplotlib.colormaps["tab10"]
    for row in objects.to_pylist():
        cid = table.ids.get(row["class_name"], 0)
        colour = cmap(cid % 10) if row["class_id"] >= 0 else (1.0, 1.0, 1.0, 1.0)
        x0, x1, y0, y1 = row["x_min_m"], row["x_max_m"], row["y_min_m"], row["y_max_m"]
        ax.add_patch(Rectangle((-y1, x0), y1 - y0, x1 - x0, fill=False, lw=1.2, ec=colour))
        text = f"{row['class_name']} {row['probability']:.2f}"
        if row["true_class_name"] is not None:
            text += f"\n(true {row['true_class_name']})"
        ax.text(-y1, x1, text, color=colour, fontsize=6, va="bottom")
    ax.set_aspect("equal")
    ax.set_xlabel("-y (right) [m]")
    ax.set_ylabel("x (forward) [m]")
    ax.set_title(f"keyframe {frame.keyframe_id}: horizontal sonar objects")
    fig.tight_layout()
    return png_bytes(fig)
