"""`overlay.png`: one keyframe's objects (classify's `objects.parquet`) drawn over its
horizontal image."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.schemas.objects import UNKNOWN_CLASS_ID
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.kernels.figure_png import png_bytes

__all__ = ["busiest_keyframe", "overlay_png"]


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
    step_r = max(1, len(ping.ranges_m) // 300)
    step_b = max(1, len(ping.angles_rad) // 256)
    r = ping.ranges_m[::step_r, None].astype(np.float64)
    a = ping.angles_rad[None, ::step_b].astype(np.float64)
    fig = Figure(figsize=(8, 6), dpi=100)
    ax = fig.add_subplot()
    img = ping.image[::step_r, ::step_b]
    vmin, vmax = float(np.percentile(img, 90)), max(float(img.max()), 1.0)
    ax.pcolormesh(-r * np.sin(a), r * np.cos(a), img, cmap="gray", vmin=vmin, vmax=vmax,
                  shading="auto", rasterized=True)  # fmt: skip
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
