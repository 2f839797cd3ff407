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


def topdown_png(
    maps_m: Mapping[str, np.ndarray],
    truth_xy_m: np.ndarray | None = None,
    trajectory_xy_m: np.ndarray | None = None,
    max_points: int = 150_000,
) -> bytes:
    """Top-down view of each map (one panel per map), points coloured by height.

    Args:
        maps_m: map name -> (n, 3) world points [m].
        truth_xy_m: (k, 2) ground-truth surface points drawn in grey, or None.
        trajectory_xy_m: (t, 2) vehicle positions drawn as a line, or None.
        max_points: draw at most this many points per panel.
    """
    clouds = {n: thin(np.asarray(p).reshape(-1, 3), max_points) for n, p in maps_m.items()}
    z_all = np.concatenate([c[:, 2] for c in clouds.values()] + [np.zeros(1)])
    vmin, vmax = float(z_all.min()), float(max(z_all.max(), z_all.min() + 1e-3))
    fig = _figure(5.2 * len(clouds) + 0.8, 5.2)
    axes = fig.subplots(1, len(clouds), squeeze=False)[0]
    sc = None
    for ax, (name, pts) in zip(axes, clouds.items(), strict=True):
        if truth_xy_m is not None and len(truth_xy_m):
            t = thin(truth_xy_m, max_points)
            ax.scatter(t[:, 0], t[:, 1], s=0.3, c="0.75", linewidths=0, label="ground truth")
        if trajectory_xy_m is not None and len(trajectory_xy_m):
            ax.plot(
                trajectory_xy_m[:, 0], trajectory_xy_m[:, 1], "-", c="k", lw=0.6, label="vehicle"
            )
        order = np.argsort(pts[:, 2], kind="stable")
        sc = ax.scatter(
            pts[order, 0], pts[order, 1], c=pts[order, 2], s=0.5, linewidths=0,
            cmap="viridis", vmin=vmin, vmax=vmax,
        )  # fmt: skip
        ax.set_title(f"{name} map ({len(maps_m[name])} points)")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.2)
    if sc is not None:
        fig.colorbar(sc, ax=list(axes), label="z [m] (0 = water surface)", shrink=0.8)
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
