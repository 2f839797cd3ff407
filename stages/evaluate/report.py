"""The evaluation report: markdown text and matplotlib figures rendered to PNG bytes.

Figures use the Agg backend into BytesIO (no files) with no timestamp or software
metadata, so the same data give the same bytes. Large clouds are thinned with a fixed
stride for drawing only (`max_points`); metrics never use the thinned clouds.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from schemas.classes import CLASS_IDS
from stages.evaluate.submaps import submaps_markdown
from stages.evaluate.trust import trust_markdown
from stages.kernels.ply import Mesh

__all__ = [
    "SidePanel",
    "error_boxplot_png",
    "render_markdown",
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


def _png(fig: Any) -> bytes:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


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
    return _png(fig)


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
    return _png(fig)


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
    return _png(fig)


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def _coverage_table(metrics: Mapping[str, Any]) -> list[str]:
    """The first table: the headline median error (`stages.evaluate.headline`) leads, raw beside."""
    vox = metrics.get("voxels", {})
    pts = metrics.get("points", {})
    errs = metrics.get("errors", {})
    comp = metrics.get("completeness", {})
    prec = metrics.get("precision", {})
    head = metrics.get("headline") or {}
    median = head.get("median_m") or {}
    # Only an aligned headline differs from the raw statistics, which then say "raw".
    raw = "raw " if head.get("frame") == "aligned" else ""
    counts = {"standard": pts.get("fused"), "semantic": None}
    if pts.get("fused") is not None and pts.get("inferred") is not None:
        counts["semantic"] = pts["fused"] + pts["inferred"]
    lead = [head["label"]] if head else []
    cols = ["map", "points", "voxels", *lead, f"{raw}median error m", f"{raw}mean error m"]
    cols += [f"{raw}p90 m", f"{raw}p95 m", "completeness", "precision"]
    if head and not raw:
        cols.remove("median error m")
    lines = ["| " + " | ".join(cols) + " |", "|---|" + "---:|" * (len(cols) - 1)]
    for name in ("standard", "semantic"):
        e = errs.get(name, {})
        cells = [name, _fmt(counts[name]), _fmt(vox.get(name))]
        cells += [f"**{_fmt(median.get(name))}**"] if head else []
        cells += [_fmt(e.get("median_m"))] if not head or raw else []
        cells += [_fmt(e.get(k)) for k in ("mean_m", "p90_m", "p95_m")]
        cells += [_fmt(comp.get(name)), _fmt(prec.get(name))]
        lines.append("| " + " | ".join(cells) + " |")
    if vox.get("standard"):
        lines.append(f"\nsemantic / standard voxels: **{vox['semantic'] / vox['standard']:.2f}x**")
    return lines


def _per_class_table(metrics: dict[str, Any]) -> list[str]:
    """Markdown lines of the per-class accounting (`stages.evaluate.class_accounting`), or none."""
    per_class = metrics.get("per_class") or {}
    classes = per_class.get("classes") or {}
    if not classes:
        return []
    lines = [
        "## Coverage by true class",
        "",
        f"Every map point takes the class of the nearest ground-truth surface; accurate voxels"
        f" hold a point within {_fmt(per_class.get('tolerance_m'))} m of it; completeness is of"
        " the class's visible surface; errors at the "
        f"{'SLAM-aligned' if per_class.get('frame') == 'aligned' else 'mapped'} positions.",
        "",
        "| class | voxels std | voxels sem | accurate std | accurate sem | gain | completeness"
        " std | completeness sem | median m fused | median m inferred |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, c in classes.items():
        std, sem = c.get("standard", {}), c.get("semantic", {})
        acc_s, acc_m = std.get("accurate_voxels"), sem.get("accurate_voxels")
        gain = f"{acc_m / acc_s:.1f}x" if acc_s else "-"
        lines.append(
            f"| {name} | {_fmt(std.get('voxels'))} | {_fmt(sem.get('voxels'))} | {_fmt(acc_s)}"
            f" | {_fmt(acc_m)} | {gain} | {_fmt(std.get('completeness'))}"
            f" | {_fmt(sem.get('completeness'))} | {_fmt(std.get('median_error_m'))}"
            f" | {_fmt((c.get('inferred') or {}).get('median_error_m'))} |"
        )
    return [*lines, "", *_assigned_class_table(per_class.get("assigned_classes") or {})]


def _assigned_class_table(classes: Mapping[str, Any]) -> list[str]:
    """Markdown lines of the error budget by assigned class, or none."""
    if not classes:
        return []
    lines = [
        "### Error by assigned class",
        "",
        "The class the classifier gave each point's object; a class's inferred median over"
        " its fused median is the per-class error budget (1.5x) that decides the classes"
        " inferred by default.",
        "",
        "| assigned class | fused points | inferred points | median m fused | median m inferred"
        " | inferred / fused |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name, c in classes.items():
        ratio = c.get("inferred_over_fused")
        lines.append(
            f"| {name} | {_fmt(c.get('fused_points'))} | {_fmt(c.get('inferred_points'))}"
            f" | {_fmt(c.get('fused_median_error_m'))} | {_fmt(c.get('inferred_median_error_m'))}"
            f" | {'-' if ratio is None else f'{ratio:.2f}x'} |"
        )
    return [*lines, ""]


def render_markdown(
    metrics: Mapping[str, Any],
    dataset: str,
    n_keyframes: int,
    figures: Sequence[str],
) -> bytes:
    """`report.md`: dataset, counts, coverage table, errors, trajectory, skipped checks.

    Args:
        metrics: the evaluate stage's metrics.json dict.
        dataset: dataset name.
        n_keyframes: number of keyframes.
        figures: file names of the PNGs written beside the report.
    """
    voxel = metrics.get("voxel_size_m")
    lines = [
        "# sonarmap report",
        "",
        f"- dataset: `{dataset}`",
        f"- keyframes: {n_keyframes}",
        f"- voxel size: {_fmt(voxel)} m",
        f"- ground truth: {'yes' if metrics.get('has_ground_truth') else 'no'}",
        "",
        "## Coverage (paper Table I)",
        "",
        *_coverage_table(metrics),
        "",
        *_per_class_table(metrics),
        *submaps_markdown(metrics.get("submaps")),
        *trust_markdown(metrics.get("trust")),
    ]
    errs = metrics.get("errors", {})
    if errs:
        lines += [
            "## Absolute error by point source",
            "",
            "| source | n | median m | mean m | p90 m | p95 m |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        for name in ("fused", "inferred"):
            e = errs.get(name, {})
            lines.append(
                f"| {name} | {_fmt(e.get('n'))} | {_fmt(e.get('median_m'))} | {_fmt(e.get('mean_m'))}"
                f" | {_fmt(e.get('p90_m'))} | {_fmt(e.get('p95_m'))} |"
            )
        lines.append("")
    comp = metrics.get("completeness", {})
    if comp:
        lines += [
            f"Completeness: fraction of {comp.get('n_samples')} visible ground-truth surface"
            f" samples of {', '.join(comp.get('classes', []))} within {comp.get('tolerance_m')} m"
            " of a map point (visible: below the water surface, inside the horizontal sonar's"
            " field of view from some keyframe and not occluded); precision: fraction of map"
            " points within the same distance of the surface, both at the mapped positions."
            " The bold median moves the map by the SE(2) alignment of the SLAM trajectory to"
            " the truth first when one was needed (see Trajectory).",
            "",
        ]
    traj = metrics.get("trajectory", {})
    if traj:
        lines += [
            "## Trajectory (ATE after SE(2) alignment)",
            "",
            f"- SLAM: {_fmt(traj.get('slam_ate_m'))} m",
            f"- dead reckoning: {_fmt(traj.get('dead_reckoning_ate_m'))} m",
            "",
        ]
    aligned = metrics.get("errors_aligned")
    if aligned:
        lines += [
            "Median map error after the same SE(2) alignment of the SLAM trajectory (rotation"
            f" {aligned['rotation_deg']:.2f} deg; a common heading bias is unobservable to"
            f" sonar-only SLAM): standard {_fmt(aligned['standard'].get('median_m'))} m,"
            f" semantic {_fmt(aligned['semantic'].get('median_m'))} m.",
            "",
        ]
    if figures:
        lines += ["## Figures", ""] + [f"![{f.rsplit('.', 1)[0]}]({f})" for f in figures] + [""]
    skipped = metrics.get("skipped", [])
    if skipped:
        lines += ["## Skipped", ""] + [f"- {s}" for s in skipped] + [""]
    return "\n".join(lines).encode("utf-8")
