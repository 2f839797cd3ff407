"""Height models that answer from coarser cells where their own are empty (beyond the
paper's Eq. 8-9, which predict nothing from a cell without data).

`CoarseFallbackModel`: a fine `HeightModel` with a twin `factor` times coarser, and
optionally a third level, the class's *profile*: one cell per coarse range cell, pooled
over the whole cross-range axis. In the object frames' height-equivalent range axis a
vertical surface returns from z = +-s at every cross-range offset, so the profile is what
all of a class's objects say about each s; a class seen in 3D only a few times (few fused
points, most fine and coarse cells empty) still predicts from it: the hierarchical
pooling of issue 39 (class-level profile, per-cell posteriors where the cells have data).
"""

from __future__ import annotations

import numpy as np

from sonarmap.stages.kernels.height_model import HeightModel, HeightQuery, weighted

__all__ = ["PROFILE_CROSS_RANGE_M", "CoarseFallbackModel"]

PROFILE_CROSS_RANGE_M = 1.0e6
"""Cross-range cell of the profile level [m]: wide enough that every object-frame
position falls into the cell centred on v = 0."""


class CoarseFallbackModel:
    """A `HeightModel` that answers from a twin with coarser cells where its own cell
    never received a measurement: a second grid, `factor` times coarser along both axes
    and centred on the origin like the first.

    All levels learn every update. A query is answered by the fine cell when it has
    data, else by the coarse cell that contains the position, else (with `profile`) by
    the profile cell of its range, else not at all (Eq. 8-9 need data).

    Args:
        fine: the model whose cells answer first.
        factor: coarse cell size over the fine one, along both axes (>= 2).
        profile: add the profile level (coarse range cells, pooled over cross-range).
    """

    def __init__(self, fine: HeightModel, factor: int, profile: bool = False) -> None:
        if factor < 2:
            raise ValueError(f"coarse factor must be >= 2, got {factor}")
        self.fine = fine
        self.coarse = HeightModel(
            fine.z_m,
            sigma_m=fine.sigma_m,
            range_cell_m=float(fine.cell_m[0] * factor),
            cross_range_cell_m=float(fine.cell_m[1] * factor),
            window_m=fine.window_m,
            update_rule=fine.update_rule,
            prior_weight=fine.prior_weight,
        )
        self.profile: HeightModel | None = None
        if profile:
            self.profile = HeightModel(
                fine.z_m,
                sigma_m=fine.sigma_m,
                range_cell_m=float(fine.cell_m[0] * factor),
                cross_range_cell_m=PROFILE_CROSS_RANGE_M,
                window_m=fine.window_m,
                update_rule=fine.update_rule,
                prior_weight=fine.prior_weight,
            )

    @property
    def n_cells(self) -> int:
        """Fine cells that received at least one measurement."""
        return self.fine.n_cells

    @property
    def updated(self) -> bool:
        return self.fine.updated

    def update(self, uv_m: np.ndarray, z_m: np.ndarray) -> int:
        """Eq. 7 in every level; returns the number of fine cells updated."""
        self.coarse.update(uv_m, z_m)
        if self.profile is not None:
            self.profile.update(uv_m, z_m)
        return self.fine.update(uv_m, z_m)

    def query(
        self, uv_m: np.ndarray, threshold: float, prior: np.ndarray | None = None
    ) -> HeightQuery:
        """The answer of the finest level whose cell has data (one MAP pass over the
        posteriors gathered from all levels; `prior` as in `HeightModel.query`)."""
        uv = np.asarray(uv_m, dtype=np.float64).reshape(-1, 2)
        levels = [m for m in (self.fine, self.coarse, self.profile) if m is not None]
        source = np.full(uv.shape[0], -1)
        rows = np.full(uv.shape[0], -1, dtype=np.int64)
        for k, model in enumerate(levels):
            todo = np.flatnonzero(source < 0)
            found = model._find(model.cell_keys(uv[todo]))
            hit = todo[found >= 0]
            source[hit], rows[hit] = k, found[found >= 0]
        seen = source >= 0
        prob = np.empty((int(seen.sum()), self.fine.z_m.size))
        slot = np.cumsum(seen) - 1  # row of each seen position in `prob`
        for k, model in enumerate(levels):
            mine = source == k
            prob[slot[mine]] = model._probabilities(rows[mine])
        return self.fine._answer(weighted(prob, prior, seen), seen, threshold)
