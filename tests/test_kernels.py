"""Stages share through artifacts and the kernel layer: infer's class models as an
artifact that submaps reads back (its key follows infer's)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from test_infer import _asymmetric_mission

from sonarmap.pipeline.engine.config.load import load_config
from sonarmap.pipeline.engine.run.runner import DatasetSpec, plan
from sonarmap.pipeline.engine.store.artifact import ArtifactRef
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
from sonarmap.pipeline.graph import all_stages, extra_sections, pipeline_stages, training_stage
from sonarmap.schemas.class_models import CLASS_CELLS_SCHEMA, CLASS_REFERENCE_SCHEMA
from sonarmap.stages.base import Input
from sonarmap.stages.infer.stage import STAGE as INFER
from sonarmap.stages.infer.stage import InferConfig, learn_and_infer
from sonarmap.stages.kernels.class_models import (
    ModelTableError,
    class_model_tables,
    restore_class_states,
)


def _relabelled(inputs: dict[str, pa.Table], class_name: str) -> dict[str, pa.Table]:
    objects = inputs["objects"]
    names = pa.array([class_name] * objects.num_rows, pa.string())
    return {**inputs, "objects": objects.set_column(2, "class_name", names)}


def _learned(class_name: str, config: InferConfig) -> tuple[pa.Table, pa.Table, dict]:
    m = _relabelled(_asymmetric_mission(), class_name)
    _, _, states = learn_and_infer(
        m["objects"], m["object_features"], m["features"], m["fused"], config
    )
    return (*class_model_tables(states), states)


def _through_parquet(table: pa.Table, path: Path) -> pa.Table:
    pq.write_table(table, path)
    return pq.read_table(path)


@pytest.mark.parametrize(
    ("class_name", "profile"),
    [("cylindrical_piling", False), ("cylindrical_piling", True), ("seawall", False)],
)
def test_class_models_read_back_answer_exactly_as_learned(
    tmp_path: Path, class_name: str, profile: bool
) -> None:
    config = InferConfig(classes=(class_name,), profile_fallback=profile)
    reference, cells, states = _learned(class_name, config)
    assert reference.schema.equals(CLASS_REFERENCE_SCHEMA)
    assert cells.schema.equals(CLASS_CELLS_SCHEMA)
    assert cells.num_rows > 0
    # object frames have a reference cloud and a coarse twin (and a profile when asked);
    # beam frames neither
    grids = set(cells.column("grid").to_pylist())
    expected = {"fine", "coarse", *(["profile"] if profile else [])}
    assert grids == (expected if class_name != "seawall" else {"fine"})
    assert (reference.num_rows > 0) == (class_name != "seawall")
    back = restore_class_states(
        _through_parquet(reference, tmp_path / "r.parquet"),
        _through_parquet(cells, tmp_path / "c.parquet"),
        config,
    )
    before, after = states[class_name], back[class_name]
    if before.frame.reference is not None:
        assert np.array_equal(before.frame.reference, after.frame.reference)
    rng = np.random.default_rng(0)
    uv = np.c_[rng.uniform(-2, 3, 4000), rng.uniform(-1.5, 1.5, 4000)]
    q0 = before.model.query(uv, config.confidence_threshold)
    q1 = after.model.query(uv, config.confidence_threshold)
    assert q0.seen.any()
    for f in dataclasses.fields(q0):
        assert np.array_equal(getattr(q0, f.name), getattr(q1, f.name), equal_nan=True)
    assert after.model.n_cells == before.model.n_cells and after.model.updated
    # and it writes the same tables again
    again = class_model_tables(back)
    assert again[0].equals(reference) and again[1].equals(cells)


def test_class_models_that_do_not_fit_the_section_are_refused_naming_the_table() -> None:
    reference, cells, _ = _learned("cylindrical_piling", InferConfig())
    with pytest.raises(ModelTableError, match=r"not in infer\.classes") as err:
        restore_class_states(reference, cells, InferConfig(classes=("seawall",)))
    assert err.value.output == "class_reference"
    with pytest.raises(ModelTableError, match="values") as err:
        restore_class_states(reference, cells, InferConfig(z_step_m=0.1))
    assert err.value.output == "class_cells"
    prob = cells.column("probability").combine_chunks()
    values = prob.values.to_numpy().copy()
    values[7] = np.nan
    bad = cells.set_column(
        cells.schema.get_field_index("probability"),
        "probability",
        pa.ListArray.from_arrays(prob.offsets, pa.array(values)),
    )
    with pytest.raises(ModelTableError, match="finite"):
        restore_class_states(reference, bad, InferConfig())


def _keys(stages: tuple, tmp_path: Path) -> dict[str, str]:
    """Each stage's artifact key, as `sonarmap run` plans them (the model given)."""
    config = load_config(all_stages(), None, (), extra_sections())
    model = ArtifactRef("train", "0" * 64, tmp_path, {"files": {}})
    dataset = DatasetSpec(tmp_path / "rec.mcap", "f" * 64, lambda _section: None)
    store = ArtifactStore(tmp_path / "store")
    planned = plan(stages, config, dataset, store, external={"train": (training_stage(), model)})
    return {p.stage.name: p.key for p in planned}


def test_bumping_infers_version_recomputes_submaps_and_what_follows(tmp_path: Path) -> None:
    stages = pipeline_stages()
    bumped = tuple(
        dataclasses.replace(s, version=s.version + 1) if s.name == INFER.name else s for s in stages
    )
    before, after = _keys(stages, tmp_path), _keys(bumped, tmp_path)
    changed = {name for name in before if before[name] != after[name]}
    assert changed == {"infer", "submaps", "voxelize", "evaluate", "map_figures"}
    submaps = next(s for s in stages if s.name == "submaps")
    assert {Input("infer", "class_reference"), Input("infer", "class_cells")} <= set(submaps.inputs)


def test_submaps_clusters_with_the_parameters_classify_used() -> None:
    from sonarmap.stages.base import Input
    from sonarmap.stages.base import StageInputError as InputRejected
    from sonarmap.stages.classify.stage import ClassifyConfig, clustering
    from sonarmap.stages.submaps.stage import STAGE as SUBMAPS
    from sonarmap.stages.submaps.stage import _clustering

    model = {"eps_m": 0.3, "min_samples": 2, "min_features": 10}
    used = clustering(ClassifyConfig(), model)
    assert used == model
    assert clustering(ClassifyConfig(eps_m=0.5, min_features=4), model) == {
        **model,
        "eps_m": 0.5,
        "min_features": 4,
    }
    # one source: classify's output, not the config sections it was resolved from
    assert Input("classify", "clustering") in SUBMAPS.inputs
    assert not {"classify", "train"} & set(SUBMAPS.reads_sections)
    assert _clustering(used) == (0.3, 2, 10)
    for bad in ({"eps_m": 0.3}, {**model, "eps_m": -1.0}, {**model, "eps_m": float("nan")},
                {**model, "min_samples": 2.5}, {**model, "min_features": True},
                {**model, "eps_m": "0.3" * 100}):  # fmt: skip
        with pytest.raises(InputRejected, match=r"classify\.clustering") as err:
            _clustering(bad)
        assert len(str(err.value)) < 120
    with pytest.raises(ValueError, match="min_samples"):
        clustering(ClassifyConfig(), {**model, "min_samples": 0})
