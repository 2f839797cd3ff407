"""The map figures: `errors.png` (paper Fig. 4 style), `map_topdown.png`, `side_view.png`.

Figures use the Agg backend into BytesIO (no files) with no timestamp or software
metadata, so the same data give the same bytes. Large clouds are thinned with a fixed
stride for drawing only (`max_points`); metrics never use the thinned clouds.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.schemas.classes import CLASS_IDS
from sonarmap.schemas.figures import SIDE_VIEW_KINDS
from sonarmap.stages.kernels.figure_png import png_bytes
from sonarmap.stages.kernels.ply import Mesh

__all__ = [
    "PNG_SIGNATURE",
    "SidePanel",
    "error_boxplot_png",
    "side_panels_from_table",
    "side_view_png",
    "thin",
    "topdown_png",
    "truth_xy_m",
]

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@dataclass(frozen=True)
class SidePanel:
    """One piling seen from the side: horizontal coordinate h [m] (along the axis
    `axis_label`) and height z [m] of its fused, inferred and true-surface points."""

    title: str
    axis_label: str
    fused_hz_m: np.ndarray  # (n, 2)
    inferred_hz_m: np.ndarray  # (m, 2)
    truth_hz_m: np.ndarray  # (k, 2)


def thin(points: np.ndarray, max_points: int) -> np.ndarray:
    """Every k-th row so that at most `max_points` remain (deterministic)."""
    step = max(1, int(np.ceil(len(points) / max_points))) if max_points > 0 else 1
    return points[::step]


def _figure(width_in: float, height_in: float) -> Any:
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), dpi=110, layout="constrained")


def error_boxplot_png(errors_m: Mapping[str, np.ndarray]) -> bytes:
    """Box plots of absolute map error per map / source (paper Fig. 4 style).

    Args:
        errors_m: name -> (n,) errors [m], drawn left to right in the mapping's order.
    """
    names = [n for n, e in errors_m.items() if len(e)]
    fig = _figure(1.6 + 1.3 * max(len(names), 1), 4.0)
    ax = fig.add_subplot()
    if names:
        ax.boxplot(
            [np.asarray(errors_m[n]) for n in names],
            tick_labels=[f"{n}\n(n={len(errors_m[n])})" for n in names],
            showfliers=False,
            whis=(5, 95),
        )
    ax.set_ylabel("absolute error to ground truth [m]")
    ax.set_title("Map error (whiskers: 5th-95th percentile)")
    ax.grid(axis="y", alpha=0.3)
    return png_bytes(fig)


def truth_xy_m(mesh: Mesh) -> np.ndarray:
    """(v, 2) xy [m] of the non-seafloor mesh vertices below the surface (`topdown_png`)."""
    cls = mesh.vertex_properties.get("class_id")
    keep = mesh.vertices[:, 2] <= 0.0
    if cls is not None:
        keep &= cls != CLASS_IDS["seafloor"]
    return mesh.vertices[keep, :2]


TOPDOWN_PX = 320
"""Cells along the longer side of a top-down panel's raster (about 1.5 display pixels a
cell at the panel's size, so no cell is lost when the raster is drawn)."""


def _grid(clouds: Sequence[np.ndarray], px: int) -> tuple[float, float, float, int, int]:
    """(x0, y0, cell, cols, rows) of a square-celled raster holding every (n, 2+) cloud."""
    xy = np.concatenate([np.asarray(c)[:, :2] for c in clouds if len(c)] + [np.zeros((1, 2))])
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    cell = max(float((hi - lo).max()), 1e-3) / px
    cols, rows = (np.floor((hi - lo) / cell).astype(int) + 1).tolist()
    return float(lo[0]), float(lo[1]), cell, cols, rows


def _highest(xy: np.ndarray, z: np.ndarray, grid: tuple[float, float, float, int, int]) -> Any:
    """Per raster cell, the largest z of the points in it (NaN where none)."""
    x0, y0, cell, cols, rows = grid
    ix = np.clip(((xy[:, 0] - x0) / cell).astype(np.int64), 0, cols - 1)
    iy = np.clip(((xy[:, 1] - y0) / cell).astype(np.int64), 0, rows - 1)
    out = np.full(rows * cols, -np.inf)
    np.maximum.at(out, iy * cols + ix, np.asarray(z, np.float64))
    out[np.isneginf(out)] = np.nan
    return out.reshape(rows, cols)


def topdown_png(
    maps_m: Mapping[str, np.ndarray],
    truth_xy_m: np.ndarray | None = None,
    trajectory_xy_m: np.ndarray | None = None,
    max_points: int = 150_000,
) -> bytes:
    """Top-down view of each map (one panel per map): a raster of square cells, each
    coloured by the height of the highest map point in it, over the ground truth's cells
    in grey (drawn as rasters, not one marker per point: the same picture at a few
    percent of the drawing time).

    Args:
        maps_m: map name -> (n, 3) world points [m].
        truth_xy_m: (k, 2) ground-truth surface points drawn in grey, or None.
        trajectory_xy_m: (t, 2) vehicle positions drawn as a line, or None.
        max_points: draw at most this many points per panel.
    """
    clouds = {n: thin(np.asarray(p).reshape(-1, 3), max_points) for n, p in maps_m.items()}
    truth = thin(np.asarray(truth_xy_m), max_points) if truth_xy_m is not None else None
    z_all = np.concatenate([c[:, 2] for c in clouds.values()] + [np.zeros(1)])
    vmin, vmax = float(z_all.min()), float(max(z_all.max(), z_all.min() + 1e-3))
    grid = _grid([*clouds.values(), *([truth] if truth is not None else [])], TOPDOWN_PX)
    x0, y0, cell, cols, rows = grid
    extent = (x0, x0 + cols * cell, y0, y0 + rows * cell)
    fig = _figure(5.2 * len(clouds) + 0.8, 5.2)
    axes = fig.subplots(1, len(clouds), squeeze=False)[0]
    shown = None
    for ax, (name, pts) in zip(axes, clouds.items(), strict=True):
        if truth is not None and len(truth):
            seen = np.isfinite(_highest(truth, np.zeros(len(truth)), grid))
            grey = np.where(seen, 0.75, np.nan)
            ax.imshow(grey, cmap="gray", vmin=0.0, vmax=1.0, extent=extent, origin="lower",
                      interpolation="nearest")  # fmt: skip
            ax.plot([], [], "s", c="0.75", ms=3, label="ground truth")
        if trajectory_xy_m is not None and len(trajectory_xy_m):
            ax.plot(
                trajectory_xy_m[:, 0], trajectory_xy_m[:, 1], "-", c="k", lw=0.6, label="vehicle"
            )
        shown = ax.imshow(
            _highest(pts[:, :2], pts[:, 2], grid), cmap="viridis", vmin=vmin, vmax=vmax,
            extent=extent, origin="lower", interpolation="nearest",
        )  # fmt: skip
        ax.set_title(f"{name} map ({len(maps_m[name])} points)")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.2)
    if shown is not None:
        fig.colorbar(shown, ax=list(axes), label="z [m] (0 = water surface)", shrink=0.8)
    return png_bytes(fig)


def side_view_png(panels: Sequence[SidePanel]) -> bytes:
    """Side views of a few pilings: true surface, fused and inferred points (h vs z)."""
    fig = _figure(2.6 * max(len(panels), 1) + 0.4, 5.0)
    axes = fig.subplots(1, max(len(panels), 1), squeeze=False, sharey=True)[0]
    for ax, p in zip(axes, panels, strict=False):
        if len(p.truth_hz_m):
            ax.scatter(*p.truth_hz_m.T, s=0.5, c="0.8", linewidths=0, label="ground truth")
        if len(p.fused_hz_m):
            ax.scatter(*p.fused_hz_m.T, s=2, c="tab:blue", linewidths=0, label="fused")
        if len(p.inferred_hz_m):
            ax.scatter(*p.inferred_hz_m.T, s=2, c="tab:orange", linewidths=0, label="inferred")
        ax.set_title(p.title, fontsize=9)
        ax.set_xlabel(f"{p.axis_label} [m]")
        ax.grid(alpha=0.2)
    axes[0].set_ylabel("z [m]")
    handles, labels = axes[0].get_legend_handles_labels()
    if handles:
        axes[0].legend(handles, labels, loc="lower left", fontsize=8, markerscale=4)
    return png_bytes(fig)


def side_panels_from_table(table: pa.Table) -> list[SidePanel]:
    """The panels of evaluate's `side_view.parquet` (`sonarmap.schemas.figures.SIDE_VIEW_SCHEMA`)."""
    panel = table.column("panel").to_numpy()
    kind = np.asarray(table.column("kind").to_pylist(), dtype=object)
    hz = np.stack([table.column("h_m").to_numpy(), table.column("z_m").to_numpy()], axis=1)
    ids, first = np.unique(panel, return_index=True)
    titles, axes = table.column("title").to_pylist(), table.column("axis_label").to_pylist()
    panels = []
    for i, row in zip(ids, first, strict=True):
        by_kind = [hz[(panel == i) & (kind == k)] for k in SIDE_VIEW_KINDS]
        panels.append(SidePanel(titles[row], axes[row], *by_kind))
    return panels
