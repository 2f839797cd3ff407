"""Stage `evaluate`: map and trajectory quality against ground truth and the
report (paper Sec. V: absolute error per map as in Fig. 4, voxel counts as in Table I).

With a ground-truth mesh (`keyframes.scene_mesh`, the simulator's PLY attachment):
absolute error of every map point (distance to the mesh), its statistics per map
(standard, semantic) and per source (fused, inferred), precision and completeness
within `tolerance_m` (definitions and the visible-surface choice:
`sonarmap.stages.kernels.mesh_metrics`), and side views of the best-covered pilings. With ground-truth
poses in `keyframes.keyframes`: ATE of the SLAM and dead-reckoning trajectories after
SE(2) alignment. Without them, the counts are still reported and `metrics["skipped"]`
says what was left out and why. The figures are the `map_figures` stage's
(`sonarmap.stages.map_figures`); the side view's data (`side_view.parquet`) is computed here.

`map.mcap`: all of it for Foxglove (`sonarmap.stages.evaluate.foxglove_scene`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.schemas.map import ERRORS_SCHEMA, MAP_NAMES
from sonarmap.schemas.sensors import Sensors
from sonarmap.stages.base import StageSettingsError
from sonarmap.stages.evaluate import STAGE
from sonarmap.stages.evaluate.class_accounting import per_class_metrics, remember_last
from sonarmap.stages.evaluate.config import EvaluateConfig
from sonarmap.stages.evaluate.foxglove_map import evaluate_map_mcap
from sonarmap.stages.evaluate.front_end import front_end_report
from sonarmap.stages.evaluate.headline import (
    headline_errors,
    poses_are_ground_truth,
    visibility_poses,
)
from sonarmap.stages.evaluate.report import render_markdown
from sonarmap.stages.evaluate.side_panels import side_panels
from sonarmap.stages.evaluate.sonar_view import SonarView
from sonarmap.stages.evaluate.submaps import JudgedMap, has_submap_rows, submap_comparison
from sonarmap.stages.evaluate.trust import trust_report
from sonarmap.stages.kernels.mesh_metrics import (
    ate_se2,
    error_stats,
    fraction_within,
    mesh_distance,
    nearest_distance,
    raycasting_scene,
    sampled_area_m2,
    se2_alignment,
    surface_samples,
)
from sonarmap.stages.kernels.ply import Mesh, decode_mesh_ply
from sonarmap.stages.kernels.voxels import map_xyz

__all__ = ["STAGE", "EvaluateConfig", "map_errors", "surface_metrics", "trajectory_errors"]

logger = logging.getLogger(__name__)


def map_errors(map_table: pa.Table, mesh: Mesh) -> tuple[pa.Table, dict[str, Any]]:
    """Absolute error of every map point and its statistics (paper Fig. 4).

    Returns:
        errors.parquet (`ERRORS_SCHEMA`: the map rows with `error_m`) and
        {"standard"|"semantic"|"fused"|"inferred": error_stats(...)}.
    """
    err = mesh_distance(raycasting_scene(mesh), map_xyz(map_table, "semantic"))
    source = np.asarray(map_table.column("source").to_pylist(), dtype=object)
    groups = {
        "standard": source == "fused",
        "semantic": np.ones(len(source), dtype=bool),
        "fused": source == "fused",
        "inferred": source == "inferred",
    }
    table = map_table.append_column("error_m", pa.array(err, pa.float64()))
    return table.cast(ERRORS_SCHEMA), {k: error_stats(err[m]) for k, m in groups.items()}


MAX_SURFACE_SAMPLES = 2_000_000
"""Surface samples one evaluation may draw: about 1.5 GB with the distance queries and
visibility tests over them (3 million took 2.3 GB). The marina's default: about 30,000."""


def surface_metrics(
    map_table: pa.Table,
    errors: pa.Table,
    mesh: Mesh,
    T_world_sonar: np.ndarray,
    config: EvaluateConfig,
    table: ClassTable = DEFAULT_TABLE,
    view: SonarView | None = None,
) -> tuple[dict[str, Any], dict[str, Any], np.ndarray]:
    """Completeness and precision of both maps (definitions: `sonarmap.stages.kernels.mesh_metrics`).

    Returns:
        completeness {"standard", "semantic", "n_samples", "classes", "tolerance_m"},
        precision {"standard", "semantic", "fused", "inferred", "tolerance_m"}, and the
        (s, 3) surface samples of the completeness classes before the visibility cut.
    """
    classes = config.completeness(table)
    ids = np.array([table.ids[c] for c in classes if c in table.ids])
    wanted = round(sampled_area_m2(mesh, ids) * config.surface_samples_per_m2)
    if wanted > MAX_SURFACE_SAMPLES:
        raise StageSettingsError(
            f"evaluate.surface_samples_per_m2 = {config.surface_samples_per_m2:g} asks for"
            f" {wanted:,} surface samples, over the {MAX_SURFACE_SAMPLES:,} an evaluation"
            " holds (bounded memory); lower it"
        )
    samples = surface_samples(mesh, ids, config.surface_samples_per_m2, config.seed)
    view = view or SonarView.of(config, None)
    seen = samples[view.visible(samples, T_world_sonar, raycasting_scene(mesh))]
    tol = config.tolerance_m
    completeness: dict[str, Any] = {
        name: fraction_within(nearest_distance(seen, map_xyz(map_table, name), tol), tol)
        for name in MAP_NAMES
    }
    completeness.update(n_samples=len(seen), classes=list(classes), tolerance_m=tol)
    err = errors.column("error_m").to_numpy()
    source = np.asarray(errors.column("source").to_pylist(), dtype=object)
    precision: dict[str, Any] = {
        "standard": fraction_within(err[source == "fused"], tol),
        "semantic": fraction_within(err, tol),
        "fused": fraction_within(err[source == "fused"], tol),
        "inferred": fraction_within(err[source == "inferred"], tol),
        "tolerance_m": tol,
    }
    return completeness, precision, samples


def _matched_xy(
    keyframes: pa.Table, poses: pa.Table
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(SLAM xy, true xy, dead-reckoning xy) of the keyframes with both; None without truth."""
    gt_x = keyframes.column("gt_x_m").to_numpy(zero_copy_only=False).astype(np.float64)
    gt_y = keyframes.column("gt_y_m").to_numpy(zero_copy_only=False).astype(np.float64)
    has = np.isfinite(gt_x) & np.isfinite(gt_y)
    if not has.any():
        return None
    kf = keyframes.column("keyframe_id").to_numpy()[has]
    gt = np.stack([gt_x[has], gt_y[has]], axis=1)
    dr = np.stack([keyframes.column(c).to_numpy()[has] for c in ("x_m", "y_m")], axis=1)
    pid = poses.column("keyframe_id").to_numpy()
    order = np.argsort(pid, kind="stable")
    idx = np.clip(np.searchsorted(pid[order], kf), 0, max(len(pid) - 1, 0))
    found = (pid[order][idx] == kf) if len(pid) else np.zeros(len(kf), bool)
    slam = np.stack([poses.column(c).to_numpy()[order][idx] for c in ("x_m", "y_m")], axis=1)
    return slam[found], gt[found], dr[found]


def trajectory_errors(keyframes: pa.Table, poses: pa.Table) -> dict[str, float | None] | None:
    """ATE [m] of SLAM and dead reckoning vs ground truth (None without ground truth)."""
    matched = _matched_xy(keyframes, poses)
    if matched is None:
        return None
    slam, gt, dr = matched
    return {
        "slam_ate_m": ate_se2(slam, gt),
        "dead_reckoning_ate_m": ate_se2(dr, gt),
        "n_keyframes": len(slam),
    }


def aligned_map_xyz(
    map_table: pa.Table, keyframes: pa.Table, poses: pa.Table
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Map points moved by the SLAM trajectory's SE(2) alignment to the truth.

    A common rotation and offset of the whole map is unobservable to sonar-only SLAM (a
    constant bias of the navigation heading rotates every pose alike); ATE removes it by
    alignment, and the map is judged the same way.

    Returns:
        ((n, 3) aligned points, (2, 2) R, (2,) t), or None without ground-truth poses.
    """
    matched = _matched_xy(keyframes, poses)
    if matched is None or len(matched[0]) == 0:
        return None
    R, t = se2_alignment(matched[0], matched[1])
    xyz = map_xyz(map_table, "semantic").copy()
    xyz[:, :2] = xyz[:, :2] @ R.T + t
    return xyz, R, t


def aligned_map_errors(
    map_table: pa.Table, aligned: tuple[np.ndarray, np.ndarray, np.ndarray], err: np.ndarray
) -> dict[str, Any]:
    """Error statistics of both maps at the aligned positions (`aligned_map_xyz`).

    Returns:
        {"standard": error_stats, "semantic": error_stats, "rotation_deg": float,
        "translation_m": [x, y]}.
    """
    _, R, t = aligned
    fused = np.asarray(map_table.column("source").to_pylist(), dtype=object) == "fused"
    return {
        "standard": error_stats(err[fused]),
        "semantic": error_stats(err),
        "rotation_deg": float(np.degrees(np.arctan2(R[1, 0], R[0, 0]))),
        "translation_m": [float(t[0]), float(t[1])],
    }


def _rows(table: Any) -> int:
    return 0 if table is None else int(table.num_rows)


def _run(config: EvaluateConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    map_table: pa.Table = inputs["voxelize.map"]
    summary: dict[str, Any] = inputs["voxelize.summary"]
    keyframes: pa.Table = inputs["keyframes.keyframes"]
    poses: pa.Table = inputs["slam.poses"]
    sensors = Sensors.of(inputs["keyframes.sensors"] or {})
    table: ClassTable = inputs.get("config.classes", DEFAULT_TABLE)
    mesh_bytes: bytes | None = inputs.get("keyframes.scene_mesh")
    metrics: dict[str, Any] = {
        "voxel_size_m": summary.get("voxel_size_m"),
        "voxels": summary.get("voxels", {}),
        "points": summary.get("points", {}),
        "has_ground_truth": mesh_bytes is not None,
        "errors": {},
        "completeness": {},
        "precision": {},
        "trajectory": {},
        "skipped": [],
        "inference": inputs.get("infer.stats") or {},
    }
    outputs: dict[str, Any] = {"errors": None, "side_view": None}
    mesh = decode_mesh_ply(mesh_bytes) if mesh_bytes is not None else None
    judged: JudgedMap | None = None
    voxel_size = float(summary.get("voxel_size_m") or 0.1)
    traj = trajectory_errors(keyframes, poses)
    if traj is None:
        metrics["skipped"].append("trajectory error: keyframes carry no ground-truth poses")
    else:
        metrics["trajectory"] = traj
    if mesh is None:
        metrics["skipped"] += [
            f"{what}: no ground-truth mesh (keyframes.scene_mesh)"
            for what in ("map errors", "completeness", "precision", "error plot", "side view")
        ]
    else:
        errors, metrics["errors"] = map_errors(map_table, mesh)
        scene = raycasting_scene(mesh)
        eval_xyz, eval_err = map_xyz(map_table, "semantic"), errors.column("error_m").to_numpy()
        aligned = aligned_map_xyz(map_table, keyframes, poses)
        if aligned is not None:
            eval_xyz, eval_err = aligned[0], mesh_distance(scene, aligned[0])
            metrics["errors_aligned"] = aligned_map_errors(map_table, aligned, eval_err)
        true_poses = poses_are_ground_truth(keyframes, poses)
        metrics["headline"] = headline_errors(
            metrics["errors"], metrics.get("errors_aligned"), true_poses
        )
        T_ws = visibility_poses(keyframes, poses, sensors.horizontal.T_base_sonar)
        view = SonarView.of(config, sensors.horizontal)  # one place
        metrics["visibility"] = view.as_dict()
        visible = remember_last(lambda samples: view.visible(samples, T_ws, scene))

        def class_figures(rows: pa.Table, xyz: np.ndarray, err: np.ndarray) -> dict[str, Any]:
            return per_class_metrics(
                rows, mesh, scene, xyz, err, voxel_size, visible,
                config.tolerance_m, config.surface_samples_per_m2, config.seed, table,
            )  # fmt: skip

        metrics["per_class"] = {
            # True poses align to themselves: the map is where it was made.
            "frame": "ground_truth_poses" if true_poses else "raw" if aligned is None else "aligned",
            **class_figures(map_table, eval_xyz, eval_err),
        }
        judged = JudgedMap(
            errors.column("error_m").to_numpy(), eval_err, eval_xyz,
            metrics["headline"], metrics["per_class"], class_figures,
        )  # fmt: skip
        metrics["completeness"], metrics["precision"], samples = surface_metrics(
            map_table, errors, mesh, T_ws, config, table, view
        )
        outputs["errors"] = errors
        outputs["side_view"] = side_panels(map_table, mesh, samples, config.side_view_pilings)
        if outputs["side_view"] is None:
            metrics["skipped"].append("side view: no map points near a piling of the mesh")
    if has_submap_rows(map_table):
        stats = inputs.get("submaps.stats") or {}
        metrics["submaps"] = submap_comparison(map_table, voxel_size, stats.get("stride"), judged)
    metrics["trust"] = trust_report(
        map_table, keyframes, poses, inputs.get("slam.factors"),
        config.trust_cell_m, config.trust_height_tolerance_m, inputs.get("slam.summary"),
    )  # fmt: skip
    metrics["front_end"] = front_end_report(
        inputs.get("features.calibration"),
        _rows(inputs.get("fuse.fused")),
        _rows(inputs.get("classify.objects")),
        keyframes.num_rows,
    )
    metrics["classifier_acceptance"] = inputs.get("classify.acceptance")
    outputs["report"] = render_markdown(metrics, keyframes.num_rows)
    outputs["metrics"] = metrics
    outputs["map_mcap"] = evaluate_map_mcap(inputs, outputs["errors"], mesh)
    return outputs
