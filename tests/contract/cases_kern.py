"""Shared-artifact cases: stage `submaps` reads infer's class models and classify's
clustering back from the store (issue 36), so a bad one is bad input.

Each case starts from a real run of the tiny mission (`cases_share`'s, made once), edits
one artifact the way a broken disk or a hostile colleague would (the manifest rehashed,
so the store's own checks pass), and forces `submaps` to read it again: exit 2 with
one line naming the file, and every artifact already computed still in the store.
"""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from tests.contract.case import Case
from tests.contract.cases_share import _fresh_run, _rehash

STORE = ("data", "store")
RERUN = ["run", "rec.mcap", "--force", "submaps"]


def _artifact(work: Path, stage: str) -> Path:
    folder = work.joinpath(*STORE, stage)
    return next(p for p in sorted(folder.iterdir()) if (p / "manifest.json").is_file())


def _edit_table(
    stage: str, name: str, change: Callable[[pa.Table], pa.Table]
) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        _fresh_run(work)
        directory = _artifact(work, stage)
        path = directory / name
        table = pq.read_table(path)
        pq.write_table(change(table).replace_schema_metadata(table.schema.metadata), path)
        _rehash(directory, name)
        return RERUN

    return build


def _edit_json(
    stage: str, name: str, change: Callable[[dict[str, Any]], Any]
) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        _fresh_run(work)
        directory = _artifact(work, stage)
        doc = json.loads((directory / name).read_text())
        (directory / name).write_text(json.dumps(change(doc)))
        _rehash(directory, name)
        return RERUN

    return build


def _lists(table: pa.Table, column: str, values: np.ndarray, offsets: pa.Array) -> pa.Table:
    return table.set_column(
        table.schema.get_field_index(column),
        column,
        pa.ListArray.from_arrays(offsets, pa.array(values, pa.float64())),
    )


def _probability(edit: Callable[[np.ndarray], np.ndarray]) -> Callable[[pa.Table], pa.Table]:
    def change(table: pa.Table) -> pa.Table:
        prob = table.column("probability").combine_chunks()
        values = edit(prob.values.to_numpy().copy())
        return _lists(table, "probability", values, prob.offsets)

    return change


def _set_nan(v: np.ndarray) -> np.ndarray:
    v[len(v) // 2] = np.nan
    return v


def _set_large(v: np.ndarray) -> np.ndarray:
    v[0] = 7.5
    return v


def _short_lists(table: pa.Table) -> pa.Table:
    """Every cell one height short of the z grid."""
    prob = table.column("probability").combine_chunks()
    n = len(prob)
    n_z = len(prob.values) // max(n, 1)
    keep = np.ones(len(prob.values), bool)
    keep[np.arange(n) * n_z + n_z - 1] = False
    offsets = pa.array(np.arange(n + 1, dtype=np.int32) * (n_z - 1), pa.int32())
    return _lists(table, "probability", prob.values.to_numpy()[keep], offsets)


def _strings(table: pa.Table, column: str, value: str) -> pa.Table:
    return table.set_column(
        table.schema.get_field_index(column),
        column,
        pa.array([value] * table.num_rows, pa.string()),
    )


def _int_column(
    column: str, edit: Callable[[np.ndarray], np.ndarray]
) -> Callable[[pa.Table], pa.Table]:
    def change(table: pa.Table) -> pa.Table:
        values = edit(table.column(column).to_numpy().copy())
        return table.set_column(table.schema.get_field_index(column), column, pa.array(values))

    return change


def _far_cell(v: np.ndarray) -> np.ndarray:
    v[0] = 1 << 40
    return v


def _duplicate_cells(v: np.ndarray) -> np.ndarray:
    return np.zeros_like(v)


def _reference_inf(table: pa.Table) -> pa.Table:
    u = table.column("u_m").to_numpy().copy()
    u[0] = np.inf
    return table.set_column(table.schema.get_field_index("u_m"), "u_m", pa.array(u))


def _refused(name: str) -> Callable[[Path, subprocess.CompletedProcess[str]], str | None]:
    """The error names the file, and infer's, classify's and the upstream artifacts
    are all still in the store (nothing already computed lost)."""

    def check(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
        if name not in done.stderr:
            return f"the error does not name {name}: {done.stderr.strip()[:200]}"
        for stage in ("keyframes", "features", "fuse", "classify", "slam", "infer"):
            if not any(work.joinpath(*STORE, stage).glob("*/manifest.json")):
                return f"the {stage} artifact is gone"
        return None

    return check


CELLS, REFERENCE, CLUSTERING = "class_cells.parquet", "class_reference.parquet", "clustering.json"
_TABLES = [
    ("NaN probability", "infer", CELLS, _probability(_set_nan)),
    ("probability above 1", "infer", CELLS, _probability(_set_large)),
    ("cells one height short of the z grid", "infer", CELLS, _short_lists),
    (
        "cells of a class infer does not model",
        "infer",
        CELLS,
        lambda t: _strings(t, "class_name", "kelp"),
    ),
    ("a grid the frame kind has not", "infer", CELLS, lambda t: _strings(t, "grid", "medium")),
    ("a cell index past the grid's range", "infer", CELLS, _int_column("cell_u", _far_cell)),
    ("every cell at the same index", "infer", CELLS, _int_column("cell_v", _duplicate_cells)),
    ("an infinite reference point", "infer", REFERENCE, _reference_inf),
    (
        "a reference cloud of another class",
        "infer",
        REFERENCE,
        lambda t: _strings(t, "class_name", "x" * 5000),
    ),
]
_JSONS = [
    ("clustering without eps_m", lambda d: {k: v for k, v in d.items() if k != "eps_m"}),
    ("negative eps_m", lambda d: {**d, "eps_m": -0.3}),
    ("eps_m a long string", lambda d: {**d, "eps_m": "9" * 5000}),
    ("fractional min_samples", lambda d: {**d, "min_samples": 2.5}),
    ("min_features a boolean", lambda d: {**d, "min_features": True}),
    ("huge min_samples", lambda d: {**d, "min_samples": 10**30}),
    ("clustering a list", lambda d: [1, 2, 3]),
]

CASES = [
    *(
        Case(
            "exit codes",
            f"submaps reading {what}",
            _edit_table(stage, name, change),
            check=_refused(name),
        )
        for what, stage, name, change in _TABLES
    ),
    *(
        Case(
            "exit codes",
            f"submaps reading {what}",
            _edit_json("classify", CLUSTERING, change),
            check=_refused(CLUSTERING),
        )
        for what, change in _JSONS
    ),
]
