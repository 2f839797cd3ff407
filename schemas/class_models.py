"""Column contracts of the class models that stage `infer` learns (paper Eq. 7) and
stage `submaps` queries its frames with (Eq. 8-9): `class_reference.parquet` and
`class_cells.parquet`.

A class model is a reference frame (object-frame classes: the ICP reference cloud of
the class, `sonarmap.stages.kernels.object_frame`) and a sparse grid of height posteriors
(`sonarmap.stages.kernels.height_model`), as they stand after the mission's last keyframe.
Floats are float64, so a model read back answers exactly as the one that was written.
"""

from __future__ import annotations

import pyarrow as pa

__all__ = ["CLASS_CELLS_SCHEMA", "CLASS_REFERENCE_SCHEMA", "MODEL_GRIDS"]

MODEL_GRIDS: tuple[str, ...] = ("fine", "coarse", "profile")
"""Values of the `grid` column: a class's own cells, the cells of its coarse fallback
twin (object-frame classes with `infer.coarse_fallback_factor` > 1) and of its profile
(those with `infer.profile_fallback` too)."""

CLASS_REFERENCE_SCHEMA = pa.schema(
    [
        pa.field("class_name", pa.string(), nullable=False),
        pa.field("u_m", pa.float64(), nullable=False),
        pa.field("v_m", pa.float64(), nullable=False),
    ]
)
"""class_reference.parquet: the reference cloud of each object-frame class in its
reference frame (u along the reference line of sight, v across it, metres), in the
cloud's own order (ICP reads it as stored). Rows grouped by class_name (sorted); a
class without rows has no reference frame yet."""

CLASS_CELLS_SCHEMA = pa.schema(
    [
        pa.field("class_name", pa.string(), nullable=False),
        pa.field("grid", pa.string(), nullable=False),
        pa.field("cell_u", pa.int64(), nullable=False),
        pa.field("cell_v", pa.int64(), nullable=False),
        pa.field("mass", pa.list_(pa.float64()), nullable=False),
        pa.field("probability", pa.list_(pa.float64()), nullable=False),
        pa.field("n_updates", pa.int64(), nullable=False),
    ]
)
"""class_cells.parquet: one row per learned cell (i, j) = (cell_u, cell_v) of a class's
height model (`grid`: MODEL_GRIDS). `mass`: the cell's normalised log posterior
(product rule) or Dirichlet counts (mixture rule) on the z grid of config section
`infer`; `probability`: its posterior probabilities (what a query reads); `n_updates`:
the Eq. 7 updates the model had (the same on every row of a class and grid). Sorted by
(class_name, grid, cell_u, cell_v)."""
