"""Stage `map_figures`: `errors.png`, `map_topdown.png`, `side_view.png`, after evaluate.

Off the critical path like `figures` (`sonarmap.stages.figures.stage`): nothing reads them and
`run --no-figures` leaves them out. They are what evaluate drew before (the same
functions on the same arrays), from the map, the errors and evaluate's
`side_view.parquet` (`sonarmap.schemas.figures`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.schemas.map import MAP_NAMES
from sonarmap.stages.kernels.ply import decode_mesh_ply
from sonarmap.stages.kernels.voxels import map_xyz
from sonarmap.stages.map_figures import STAGE
from sonarmap.stages.map_figures.config import MapFiguresConfig
from sonarmap.stages.map_figures.plots import (
    error_boxplot_png,
    side_panels_from_table,
    side_view_png,
    topdown_png,
    truth_xy_m,
)

__all__ = ["STAGE", "MapFiguresConfig"]


def _run(_config: MapFiguresConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    map_table: pa.Table = inputs["voxelize.map"]
    poses: pa.Table = inputs["slam.poses"]
    mesh_bytes: bytes | None = inputs.get("keyframes.scene_mesh")
    errors: pa.Table | None = inputs.get("evaluate.errors")
    side: pa.Table | None = inputs.get("evaluate.side_view")
    outputs: dict[str, Any] = {"errors": None, "side_view": None}
    if errors is not None:
        err = errors.column("error_m").to_numpy()
        source = np.asarray(errors.column("source").to_pylist(), dtype=object)
        outputs["errors"] = error_boxplot_png(
            {
                "standard": err[source == "fused"],
                "semantic": err,
                "inferred only": err[source == "inferred"],
            }
        )
    if side is not None and side.num_rows:
        outputs["side_view"] = side_view_png(side_panels_from_table(side))
    truth_xy = None if mesh_bytes is None else truth_xy_m(decode_mesh_ply(mesh_bytes))
    outputs["map_topdown"] = topdown_png(
        {name: map_xyz(map_table, name) for name in MAP_NAMES},
        truth_xy,
        np.stack([poses.column("x_m").to_numpy(), poses.column("y_m").to_numpy()], axis=1),
    )
    return outputs
