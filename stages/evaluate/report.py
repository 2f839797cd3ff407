"""The evaluation report: markdown text (its figures are the `map_figures` stage's,
`sonarmap.stages.map_figures`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from sonarmap.stages.evaluate.front_end import front_end_markdown
from sonarmap.stages.evaluate.submaps import submaps_markdown
from sonarmap.stages.evaluate.trust import trust_markdown

__all__ = ["render_markdown"]


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def _coverage_table(metrics: Mapping[str, Any]) -> list[str]:
    """The first table: the headline median error (`sonarmap.stages.evaluate.headline`) leads, raw beside."""
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
    cols += [f"{raw}p90 m", f"{raw}p95 m", f"{raw}completeness", f"{raw}precision"]
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


_FRAMES = {"aligned": "SLAM-aligned", "ground_truth_poses": "mapped (true poses)"}


def _per_class_table(metrics: dict[str, Any]) -> list[str]:
    """Markdown lines of the per-class accounting (`sonarmap.stages.evaluate.class_accounting`), or none."""
    per_class = metrics.get("per_class") or {}
    classes = per_class.get("classes") or {}
    if not classes:
        return []
    lines = [
        "## Coverage by true class",
        "",
        f"Every map point takes the class of the nearest ground-truth surface; accurate voxels"
        f" hold a point within {_fmt(per_class.get('tolerance_m'))} m of it; completeness is of"
        " the class's visible surface; completeness and errors at the "
        f"{_FRAMES.get(per_class.get('frame'), 'mapped')} positions.",
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


def _acceptance_markdown(block: Mapping[str, Any] | None) -> list[str]:
    """The report's "Classifier" section: the share of this recording's objects the CNN is
    sure of, in single views and pooled, beside its validation objects' share
    (`sonarmap.stages.classify.acceptance`)."""
    if not block or not block.get("objects"):
        return []
    lines = [
        "## Classifier",
        "",
        f"Objects the CNN is sure of (p > {_fmt(block.get('threshold'))}), of"
        f" {block['objects']}: {_fmt(block.get('sure_fraction'))} in single views,"
        f" {_fmt(block.get('pooled_sure_fraction'))} pooled over the keyframes that see them"
        f" (its validation objects, single views: {_fmt(block.get('validation_sure_fraction'))}).",
        "",
    ]
    if block.get("unconfirmed"):
        lines += [
            f"{block['unconfirmed']} objects sure to be a compact class (a piling) stay"
            f" unknown: fewer than {block.get('min_views')} sightings of their place"
            f" (`classify.min_views`), or sighted by under {block.get('min_seen_share')} of"
            " the keyframes whose fan covered it (`classify.min_seen_share`).",
            "",
        ]
    return [*lines, *[f"- **warning:** {w}" for w in block.get("warnings") or []], ""]


def _visibility_line(view: Mapping[str, Any] | None) -> list[str]:
    """Where the visible surface (completeness' denominator) ends, and whose figures."""
    if not view:
        return []
    said = view.get("source") or {}

    def part(text: str, name: str) -> str:
        source = said.get(name, "default")
        return (
            f"{text} ({'the recording does not say: default' if source == 'default' else source})"
        )

    return [
        "- visible surface: "
        + ", ".join(
            (
                part(
                    f"{_fmt(view.get('min_range_m'), 1)}-{_fmt(view.get('max_range_m'), 1)} m",
                    "max_range_m",
                ),
                part(f"fan {_fmt(view.get('fan_deg'), 1)} deg", "fan_deg"),
                part(f"aperture {_fmt(view.get('aperture_deg'), 1)} deg", "aperture_deg"),
            )
        )
    ]


def render_markdown(metrics: Mapping[str, Any], n_keyframes: int) -> bytes:
    """`report.md`: counts, coverage table, errors, trajectory, skipped checks. It names
    no file: its key holds the recording's content, not its name (the run's record and
    summary say which file it was).

    Args:
        metrics: the evaluate stage's metrics.json dict.
        n_keyframes: number of keyframes.
    """
    voxel = metrics.get("voxel_size_m")
    lines = [
        "# sonarmap report",
        "",
        f"- keyframes: {n_keyframes}",
        f"- voxel size: {_fmt(voxel)} m",
        f"- ground truth: {'yes' if metrics.get('has_ground_truth') else 'no'}",
        *_visibility_line(metrics.get("visibility")),
        "",
        "## Coverage (paper Table I)",
        "",
        *_coverage_table(metrics),
        "",
        *_per_class_table(metrics),
        *submaps_markdown(metrics.get("submaps")),
        *trust_markdown(metrics.get("trust")),
        *front_end_markdown(metrics.get("front_end")),
        *_acceptance_markdown(metrics.get("classifier_acceptance")),
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
    skipped = metrics.get("skipped", [])
    if skipped:
        lines += ["## Skipped", ""] + [f"- {s}" for s in skipped] + [""]
    return "\n".join(lines).encode("utf-8")
