"""Stage `figures`: `overlay.png` and `trajectory.png`, drawn off the critical path.

No stage that makes the map waits for a figure, and none imports matplotlib: the figures
are stages of their own that nothing reads (`run --no-figures` leaves them out of the
plan). There are two, so each starts as soon as its data exist: this one after classify
and slam (it runs beside infer, submaps, voxelize and evaluate), `map_figures` after
evaluate (`sonarmap.stages.map_figures`).

- `overlay.png`: the objects of the keyframe with the most accepted objects over its
  horizontal image (`sonarmap.stages.figures.overlay`; off with `overlay: false`).
- `trajectory.png`: the SLAM estimate with dead reckoning and ground truth, the features
  registered with it and the loop closures (`sonarmap.stages.figures.trajectory`).

They are what classify and slam drew before (the same functions on the same arrays),
from the stored artifacts and slam's `plot_points.parquet` (`sonarmap.schemas.figures`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.stages.base import Input, StageInputError
from sonarmap.stages.figures import STAGE
from sonarmap.stages.figures.config import FiguresConfig
from sonarmap.stages.figures.overlay import busiest_keyframe, overlay_png
from sonarmap.stages.figures.trajectory import trajectory_png

__all__ = ["STAGE", "FiguresConfig"]


def _se2(table: pa.Table, prefix: str = "") -> np.ndarray:
    """(K, 3) x, y, yaw columns of a poses or keyframes table."""
    names = ("x_m", "y_m", "yaw_rad")
    return np.stack([table.column(prefix + n).to_numpy() for n in names], axis=1).astype(np.float64)


def _loops(factors: pa.Table, ids: np.ndarray) -> np.ndarray:
    """(L, 2) keyframe indices (rows of `ids`) of the accepted loop closures."""
    kind = np.asarray(factors.column("type").to_pylist(), dtype=object)
    status = np.asarray(factors.column("status").to_pylist(), dtype=object)
    accepted = (kind == "loop") & (status == "accepted")
    ends = [factors.column(c).to_numpy()[accepted] for c in ("key_from", "key_to")]
    order = np.argsort(ids, kind="stable")
    return np.stack([order[np.searchsorted(ids[order], e)] for e in ends], axis=1).reshape(-1, 2)


def _trajectory(inputs: Mapping[str, Any]) -> bytes:
    poses: pa.Table = inputs["slam.poses"]
    keyframes: pa.Table = inputs["keyframes.keyframes"]
    ids = poses.column("keyframe_id").to_numpy()
    if not np.array_equal(keyframes.column("keyframe_id").to_numpy(), ids):
        raise StageInputError(Input("slam", "poses"), "keyframe ids differ from keyframes'")
    gt = None if keyframes.column("gt_x_m").null_count else _se2(keyframes, "gt_")
    loops = _loops(inputs["slam.factors"], ids)
    cloud: pa.Table = inputs["slam.plot_points"]
    mode = inputs["config.slam"].mode
    return trajectory_png(
        _se2(poses),
        _se2(keyframes),
        gt,
        np.stack([cloud.column("x_m").to_numpy(), cloud.column("y_m").to_numpy()], axis=1),
        loops,
        f"slam ({mode}): {len(ids)} keyframes, {len(loops)} loop closures",
    )


def _overlay(inputs: Mapping[str, Any]) -> bytes | None:
    objects: pa.Table = inputs["classify.objects"]
    if objects.num_rows == 0:
        return None
    chosen, rows = busiest_keyframe(objects)
    ids = inputs["keyframes.keyframes"].column("keyframe_id").to_numpy()
    where = np.flatnonzero(ids == chosen)
    frame = inputs["keyframes.frames"][int(where[0])] if len(where) else None
    if frame is None or frame.keyframe_id != chosen:
        raise StageInputError(
            Input("keyframes", "frames"), f"no images of keyframe {chosen} (classify's objects)"
        )
    table: ClassTable = inputs.get("config.classes", DEFAULT_TABLE)
    return overlay_png(frame, rows, table)


def _run(config: FiguresConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    return {
        "overlay": _overlay(inputs) if config.overlay else None,
        "trajectory": _trajectory(inputs),
    }
