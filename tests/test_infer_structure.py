"""Whole-structure inference (`sonarmap.stages.kernels.beam_frame`): walls and hulls against simulator truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute
import pytest
from test_infer import real_stage_tables

from sonarmap.sim.config import MissionConfig, SimConfig
from sonarmap.sim.dataset import simulate
from sonarmap.sim.scene import load_scene
from sonarmap.stages.infer.config import DEFAULT_CLASSES
from sonarmap.stages.infer.stage import InferConfig, infer_mission
from sonarmap.stages.kernels.beam_frame import beam_anchor_range, beam_model_coords
from sonarmap.stages.kernels.geometry import se3_from_pose as pose_to_matrix
from tests.fixtures import keyframe_indices, n_voxels, to_world

REPO = Path(__file__).resolve().parents[1]
NO_BORROWING = InferConfig(unknown_argmax_classes=(), borrowed_models={})


def test_beam_frame_puts_a_vertical_wall_at_its_true_height() -> None:
    """Along one beam, a vertical plane at distance d returns at R = sqrt(d^2 + z^2); the
    height-equivalent coordinate recovers |z| exactly, from any distance."""
    for d in (4.0, 11.0, 23.0):
        z = np.linspace(-d * np.tan(np.deg2rad(10)), d * np.tan(np.deg2rad(10)), 41)
        r = np.hypot(d, z)
        anchor = beam_anchor_range(np.zeros(r.size, int), np.zeros(r.size, int), r, gap_m=0.3)
        np.testing.assert_allclose(anchor, d)
        s = beam_model_coords(r, anchor, "height_equivalent", None)
        np.testing.assert_allclose(s[:, 0], np.abs(z), atol=1e-9)
        assert np.all(s[:, 1] == 0.0)


def test_beam_anchor_starts_a_run_per_object_beam_and_surface() -> None:
    obj = np.array([0, 0, 0, 0, 1, 0, 0])
    beam = np.array([3, 3, 3, 3, 3, 4, 4])
    r = np.array([5.0, 5.05, 5.1, 6.0, 5.5, 7.0, 7.05])  # 6.0: a surface behind (gap 0.9)
    anchor = beam_anchor_range(obj, beam, r, gap_m=0.3)
    np.testing.assert_allclose(anchor, [5.0, 5.0, 5.0, 6.0, 5.5, 7.0, 7.0])
    # Input order does not matter.
    perm = np.array([6, 2, 4, 0, 5, 3, 1])
    np.testing.assert_allclose(beam_anchor_range(obj[perm], beam[perm], r[perm], 0.3), anchor[perm])
    offset = beam_model_coords(r, anchor, "offset", 2.0)
    np.testing.assert_allclose(offset[:, 0], r - anchor)
    np.testing.assert_allclose(offset[:, 1], anchor)


def _mission(scene: str, seed: int, goals: int | None = None):
    """Real stage tables of a mission: 4 goals cut at 150 s, or all of `goals` goals."""
    mission = (
        MissionConfig(n_goals=4, duration_s=150.0)
        if goals is None
        else MissionConfig(n_goals=goals)
    )
    config = SimConfig(mission=mission)
    run = simulate(load_scene(REPO / "configs" / "scenes" / f"{scene}.yaml"), config, seed)
    frames = keyframe_indices(run, 4.0)
    T = {
        k: pose_to_matrix(run.frame(i).gt_pose) @ run.frame(i).T_base_sonar["horizontal"]
        for k, i in enumerate(frames)
    }
    return run, T, real_stage_tables(run, 4.0)


@pytest.mark.parametrize(("scene", "class_name"), [("quay", "seawall"), ("moorings", "boat_hull")])
def test_extended_structure_is_predicted_on_the_true_surface(scene: str, class_name: str) -> None:
    """Real CFAR features and fusion on a wall-only and a hull-only scene: the beam-frame
    model multiplies the covered surface at an error close to the fused points'."""
    run, T, (objects, links, features, fused) = _mission(scene, seed=0)
    config = InferConfig(classes=(*DEFAULT_CLASSES, "boat_hull"))  # hulls: opt-in
    points, stats = infer_mission(objects, links, features, fused, config)
    inferred = points.filter(pa.compute.equal(points.column("source"), "inferred"))
    assert set(inferred.column("class_name").to_pylist()) == {class_name}
    assert stats["classes"][class_name]["frame"] == "beam"
    fused_world = to_world(fused, T)
    inferred_world = to_world(inferred, T)
    d_fused = run.world.distance(fused_world)
    d_inferred = run.world.distance(inferred_world)
    assert np.median(d_inferred) <= 1.5 * np.median(d_fused)
    assert np.median(d_inferred) <= 0.25
    accurate = n_voxels(np.vstack([fused_world, inferred_world])[np.r_[d_fused, d_inferred] <= 0.1])
    assert accurate >= 3 * n_voxels(fused_world[d_fused <= 0.1])
    # Paper's behaviour one line away: piling classes only, nothing inferred here.
    paper = infer_mission(
        objects, links, features, fused, InferConfig(classes=("cylindrical_piling",))
    )[0]
    assert not pa.compute.any(pa.compute.equal(paper.column("source"), "inferred")).as_py()


def test_the_loss_accounting_matches_the_output_and_unseen_cells_predict_nothing() -> None:
    """The funnel of `stats` counts what the points table holds; returns whose cell the
    model never saw (far above or below any fused height) give no point."""
    _, _, (objects, links, features, fused) = _mission("quay", seed=1)
    points, stats = infer_mission(objects, links, features, fused, InferConfig())
    funnel = stats["classes"]["seawall"]
    inferred = pa.compute.equal(points.column("source"), "inferred")
    assert pa.compute.sum(inferred).as_py() == funnel["inferred_points"]
    assert funnel["seen_returns"] < funnel["queried_returns"]
    assert funnel["predicted_returns"] <= funnel["seen_returns"]
    assert (
        funnel["predicted_returns"] <= funnel["inferred_points"] <= 2 * funnel["predicted_returns"]
    )
    assert stats["horizontal_returns"] >= stats["clustered_returns"] > 0


@pytest.fixture(scope="module")
def quay():
    return _mission("quay", seed=0)


def _every_third_wall_as(objects: pa.Table, class_name: str) -> tuple[pa.Table, np.ndarray]:
    """Every third seawall object relabelled `class_name`, as a classifier's confusion;
    also the true names."""
    names = np.asarray(objects.column("class_name").to_pylist(), dtype=object)
    confused = (names == "seawall") & (np.arange(names.size) % 3 == 0)
    relabelled = objects.set_column(
        objects.schema.get_field_index("class_name"),
        "class_name",
        pa.array(np.where(confused, class_name, names).tolist()),
    )
    return relabelled, names


def test_unknown_objects_can_borrow_their_arg_max_class_model_without_teaching_it(quay) -> None:
    """`unknown_argmax_classes`: an object the classifier was not sure of, whose arg-max
    class is seawall, gets heights from the seawall model (on the true wall), and never
    updates it."""
    run, T, (objects, links, features, fused) = quay
    objects, names = _every_third_wall_as(objects, "unknown")
    objects = objects.append_column("argmax_class_name", pa.array(names.tolist()))
    plain, plain_stats = infer_mission(objects, links, features, fused, NO_BORROWING)
    routed, routed_stats = infer_mission(
        objects,
        links,
        features,
        fused,
        InferConfig(unknown_argmax_classes=("seawall",), borrowed_models={}, borrow_min_extent_m=0),
    )
    unknown_inferred = pa.compute.and_(
        pa.compute.equal(routed.column("source"), "inferred"),
        pa.compute.equal(routed.column("class_name"), "unknown"),
    )
    assert pa.compute.sum(unknown_inferred).as_py() > 0
    assert not pa.compute.any(
        pa.compute.and_(
            pa.compute.equal(plain.column("source"), "inferred"),
            pa.compute.equal(plain.column("class_name"), "unknown"),
        )
    ).as_py()
    # the seawall model learnt exactly the same with and without the borrowers
    assert routed_stats["classes"]["seawall"] == plain_stats["classes"]["seawall"]
    borrowed = routed.filter(unknown_inferred)
    d_borrowed = run.world.distance(to_world(borrowed, T))
    d_fused = run.world.distance(to_world(fused, T))
    assert np.median(d_borrowed) <= 1.5 * np.median(d_fused)
    with pytest.raises(ValueError, match="must be an inferred class"):
        InferConfig(classes=("seawall",), unknown_argmax_classes=("cylindrical_piling",))


def test_a_class_without_a_model_can_borrow_a_beam_class_model_without_teaching_it(quay) -> None:
    """`borrowed_models`: objects labelled truss (on the marina mostly wall sections the
    classifier confused) take heights from the seawall model, on the true wall, keep
    their own class, and never update the model."""
    run, T, (objects, links, features, fused) = quay
    objects, _ = _every_third_wall_as(objects, "truss")
    plain, plain_stats = infer_mission(objects, links, features, fused, NO_BORROWING)

    def lent_config(min_extent_m: float) -> InferConfig:
        return InferConfig(
            unknown_argmax_classes=(),
            borrowed_models={"truss": "seawall"},
            borrow_min_extent_m=min_extent_m,
        )

    lent, lent_stats = infer_mission(objects, links, features, fused, lent_config(0.0))

    def truss_inferred(points: pa.Table) -> pa.Array:
        return pa.compute.and_(
            pa.compute.equal(points.column("source"), "inferred"),
            pa.compute.equal(points.column("class_name"), "truss"),
        )

    assert not pa.compute.any(truss_inferred(plain)).as_py()
    assert (
        pa.compute.sum(truss_inferred(lent)).as_py()
        == (lent_stats["classes"]["truss"]["inferred_points"])
        > 0
    )
    assert lent_stats["classes"]["truss"]["updated_objects"] == 0
    assert lent_stats["classes"]["seawall"] == plain_stats["classes"]["seawall"]
    d_lent = run.world.distance(to_world(lent.filter(truss_inferred(lent)), T))
    d_fused = run.world.distance(to_world(fused, T))
    assert np.median(d_lent) <= 1.5 * np.median(d_fused)
    # the extent gate: only objects whose returns span at least that long borrow
    n_gated = [
        pa.compute.sum(
            truss_inferred(infer_mission(objects, links, features, fused, lent_config(e))[0])
        ).as_py()
        or 0
        for e in (8.0, 16.0, 24.0, 1000.0)
    ]
    assert pa.compute.sum(truss_inferred(lent)).as_py() >= n_gated[0] >= n_gated[1]
    assert n_gated[1] >= n_gated[2] > n_gated[3] == 0
    assert n_gated[0] > n_gated[2]
    with pytest.raises(ValueError, match="beam-frame"):
        InferConfig(borrowed_models={"truss": "cylindrical_piling"})  # object frame
    with pytest.raises(ValueError, match="without a model"):
        InferConfig(classes=(*DEFAULT_CLASSES, "truss"), borrowed_models={"truss": "seawall"})
