"""The class models of a mission (paper Sec. IV.D, Eq. 7): their state, the settings
they are built from, and their tables (`sonarmap.schemas.class_models`).

Stage `infer` learns one model per inferred class (`ClassState`: reference frame and
height model) and writes them; stage `submaps` reads them back and queries its frames
with them (Eq. 8-9, `sonarmap.stages.kernels.class_query`), so it never relearns them and its
key follows infer's.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import partial
from typing import Literal, Protocol

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from sonarmap.schemas.class_models import CLASS_CELLS_SCHEMA, CLASS_REFERENCE_SCHEMA
from sonarmap.schemas.classes import DEFAULT_TABLE
from sonarmap.stages.kernels.choices import DEFAULT_FRAME_KINDS, FrameKind
from sonarmap.stages.kernels.fallback_model import CoarseFallbackModel
from sonarmap.stages.kernels.height_model import HeightModel, UpdateRule, z_grid
from sonarmap.stages.kernels.object_frame import ClassFrame, IcpParams

__all__ = [
    "DEFAULT_FRAME_KINDS",
    "ClassModelSettings",
    "ClassState",
    "FrameKind",
    "ModelTableError",
    "class_model_tables",
    "inferred_classes",
    "new_class_states",
    "restore_class_states",
]


def inferred_classes(config: ClassModelSettings) -> tuple[str, ...]:
    """`config.classes`, or the default table's inferred classes where unresolved (None:
    a section not yet resolved with the run's table, `InferConfig.with_table`)."""
    return DEFAULT_TABLE.inferred if config.classes is None else config.classes


class ClassModelSettings(Protocol):
    """What the class models read of config section `infer` (`InferConfig`)."""

    @property
    def classes(self) -> tuple[str, ...] | None: ...
    @property
    def unknown_argmax_classes(self) -> tuple[str, ...]: ...
    @property
    def borrowed_models(self) -> dict[str, str]: ...
    @property
    def borrow_min_extent_m(self) -> float: ...
    @property
    def beam_gap_m(self) -> float: ...
    @property
    def beam_cell_m(self) -> float: ...
    @property
    def beam_update_rule(self) -> UpdateRule: ...
    @property
    def beam_range_cell_m(self) -> float | None: ...
    @property
    def beam_object_prior_m(self) -> float | None: ...
    @property
    def beam_object_prior_floor(self) -> float: ...
    @property
    def z_min_m(self) -> float: ...
    @property
    def z_max_m(self) -> float: ...
    @property
    def z_step_m(self) -> float: ...
    @property
    def sigma_m(self) -> float: ...
    @property
    def range_axis(self) -> Literal["offset", "height_equivalent"]: ...
    @property
    def range_cell_m(self) -> float: ...
    @property
    def cross_range_cell_m(self) -> float: ...
    @property
    def coarse_fallback_factor(self) -> int: ...
    @property
    def profile_fallback(self) -> bool: ...
    @property
    def confidence_threshold(self) -> float: ...
    @property
    def confidence_window_m(self) -> float: ...
    @property
    def max_elevation_deg(self) -> float: ...
    def frame_kind(self, class_name: str) -> FrameKind: ...
    def icp_params(self) -> IcpParams: ...


@dataclass
class ClassState:
    """Reference frame and height model of one class; `empty_model` makes the model anew
    (a provisional reference frame that gives way takes its model with it)."""

    frame: ClassFrame
    model: HeightModel | CoarseFallbackModel
    empty_model: Callable[[], HeightModel | CoarseFallbackModel]


def new_class_states(config: ClassModelSettings) -> dict[str, ClassState]:
    """An empty model (no reference frame, no cells) for every inferred class."""
    z = z_grid(config.z_min_m, config.z_max_m, config.z_step_m)
    states = {}
    for c in inferred_classes(config):
        make = partial(_height_model, z, config, config.frame_kind(c))
        states[c] = ClassState(ClassFrame(config.icp_params()), make(), make)
    return states


def _height_model(
    z: np.ndarray, config: ClassModelSettings, kind: FrameKind
) -> HeightModel | CoarseFallbackModel:
    """A class's height model; beam frames have cells (s, R0) (`sonarmap.stages.kernels.beam_frame`)."""
    if kind == "beam":
        cells = (config.beam_cell_m, config.beam_range_cell_m or 1.0)
        rule = config.beam_update_rule
    else:
        cells = (config.range_cell_m, config.cross_range_cell_m)
        rule = "product"
    model = HeightModel(z, config.sigma_m, *cells, config.confidence_window_m, rule)
    if kind == "object" and config.coarse_fallback_factor > 1:
        return CoarseFallbackModel(model, config.coarse_fallback_factor, config.profile_fallback)
    return model


def _grids(model: HeightModel | CoarseFallbackModel) -> dict[str, HeightModel]:
    if isinstance(model, CoarseFallbackModel):
        grids = {"coarse": model.coarse, "fine": model.fine}
        return grids if model.profile is None else {**grids, "profile": model.profile}
    return {"fine": model}


def _lists(values: np.ndarray) -> pa.ListArray:
    """(n, k) float64 rows as a list<float64> array (one list per row)."""
    n, k = values.shape
    offsets = pa.array(np.arange(n + 1, dtype=np.int32) * k, pa.int32())
    return pa.ListArray.from_arrays(offsets, pa.array(values.reshape(-1), pa.float64()))


def class_model_tables(states: Mapping[str, ClassState]) -> tuple[pa.Table, pa.Table]:
    """The reference clouds (`CLASS_REFERENCE_SCHEMA`) and the height-model cells
    (`CLASS_CELLS_SCHEMA`) of every class, in schema order."""
    refs, cells = [CLASS_REFERENCE_SCHEMA.empty_table()], [CLASS_CELLS_SCHEMA.empty_table()]
    for c in sorted(states):
        ref = states[c].frame.reference
        if ref is not None and len(ref):
            cloud = np.asarray(ref, np.float64).reshape(-1, 2)
            refs.append(
                pa.table(
                    [pa.array([c] * len(cloud), pa.string()), cloud[:, 0], cloud[:, 1]],
                    schema=CLASS_REFERENCE_SCHEMA,
                )
            )
        for grid, model in sorted(_grids(states[c].model).items()):
            ij, mass, prob = model.cells()
            n = ij.shape[0]
            cells.append(
                pa.table(
                    [
                        pa.array([c] * n, pa.string()),
                        pa.array([grid] * n, pa.string()),
                        ij[:, 0],
                        ij[:, 1],
                        _lists(mass),
                        _lists(prob),
                        np.full(n, model.n_updates, np.int64),
                    ],
                    schema=CLASS_CELLS_SCHEMA,
                )
            )
    return pa.concat_tables(refs), pa.concat_tables(cells)


class ModelTableError(ValueError):
    """A class-model table that does not fit the config it is read with.

    `output` is the table's output name ("class_reference" or "class_cells")."""

    def __init__(self, output: str, reason: str) -> None:
        super().__init__(f"{output}: {reason}")
        self.output = output
        self.reason = reason


def _matrix(column: pa.ChunkedArray, n_z: int, what: str) -> np.ndarray:
    """(n, n_z) finite float64 rows of a list<float64> column of n_z values each."""
    flat = pa.concat_arrays(column.chunks) if column.num_chunks else pa.array([], column.type)
    if flat.null_count or pc.any(pc.not_equal(pc.list_value_length(flat), n_z)).as_py():
        raise ValueError(f"{what}: every cell needs {n_z} values (the infer z grid)")
    values = flat.flatten().to_numpy(zero_copy_only=False).reshape(-1, n_z)
    if not np.isfinite(values).all():
        raise ValueError(f"{what}: values must be finite")
    return values


def restore_class_states(
    reference: pa.Table, cells: pa.Table, config: ClassModelSettings
) -> dict[str, ClassState]:
    """The class models of `class_model_tables`, read back for `config` (the section
    they were learned with): each answers queries exactly as the written one.

    Raises:
        ModelTableError: a table names a class or grid that `config` has no model for,
            or holds values its model cannot take (cells off the z grid, non-finite
            numbers, probabilities outside [0, 1]).
    """
    states = new_class_states(config)
    try:
        _restore_references(reference, states)
    except ValueError as err:
        raise ModelTableError("class_reference", str(err)) from err
    try:
        _restore_cells(cells, states)
    except ValueError as err:
        raise ModelTableError("class_cells", str(err)) from err
    return states


def _classes(table: pa.Table, states: Mapping[str, ClassState]) -> np.ndarray:
    names = table.column("class_name").to_numpy(zero_copy_only=False)
    unknown = sorted(set(names.tolist()) - set(states))
    if unknown:
        raise ValueError(f"class {str(unknown[0])[:40]!r} is not in infer.classes")
    return names


def _restore_references(reference: pa.Table, states: Mapping[str, ClassState]) -> None:
    names = _classes(reference, states)
    uv = np.stack([reference.column(n).to_numpy() for n in ("u_m", "v_m")], axis=1)
    if not np.isfinite(uv).all():
        raise ValueError("reference points must be finite")
    for c, state in states.items():
        mine = names == c
        if mine.any():
            state.frame.reference = uv[mine]


def _restore_cells(cells: pa.Table, states: Mapping[str, ClassState]) -> None:
    cell_class = _classes(cells, states)
    grid = cells.column("grid").to_numpy(zero_copy_only=False)
    for c, state in states.items():
        grids = _grids(state.model)
        for g in np.unique(grid[cell_class == c]).tolist():
            if g not in grids:
                raise ValueError(f"class {c}: no {str(g)[:20]!r} grid for its frame kind")
            part = cells.take(pa.array(np.flatnonzero((cell_class == c) & (grid == g))))
            n_z = grids[g].z_m.size
            prob = _matrix(part.column("probability"), n_z, f"class {c} probability")
            if ((prob < 0) | (prob > 1)).any():
                raise ValueError(f"class {c}: probabilities outside [0, 1]")
            ij = np.stack([part.column(n).to_numpy() for n in ("cell_u", "cell_v")], axis=1)
            grids[g].restore(
                ij,
                _matrix(part.column("mass"), n_z, f"class {c} mass"),
                prob,
                int(part.column("n_updates").to_numpy()[0]),
            )
