"""Stage `infer` (paper Sec. IV.D-E): frames, accuracy and coverage against simulator truth."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute
import pytest

import sonarmap.stages.infer.stage as infer_module
from sonarmap.schemas.classes import CLASS_NAMES, DEFAULT_TABLE, PILING_CLASSES
from sonarmap.schemas.points import POINTS_SCHEMA
from sonarmap.sim.config import SimConfig
from sonarmap.sim.dataset import SimRun, simulate
from sonarmap.sim.scene import load_scene
from sonarmap.stages.infer.stage import STAGE, InferConfig, infer_mission, infer_points
from sonarmap.stages.kernels.object_frame import object_origin, to_object_frame
from tests.fixtures import TruthTables, keyframe_indices, n_voxels, to_world, truth_tables

REPO = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------------------------
# Synthetic asymmetric object: catches mirrored bearing axes and mismatched origins.


def _l_object() -> tuple[np.ndarray, np.ndarray]:
    """World points (n, 3) of an L-shaped wall at x ~ 8 m and their true heights.

    The left half (y > 0) returns from z = +0.6 m, the right half from z = -0.6 m
    (sonar at z = 0), and a short leg runs back from the left end: asymmetric in both
    footprint and height.
    """
    y = np.linspace(-0.6, 0.6, 49)
    wall = np.c_[np.full(y.size, 8.0), y]
    leg = np.c_[np.linspace(8.05, 8.5, 10), np.full(10, 0.6)]
    xy = np.vstack([wall, wall + np.array([0.05, 0.0]), leg])
    z = np.where(xy[:, 1] > 0, 0.6, -0.6)
    return np.c_[xy, z], z


def _sighting(
    kf: int, pose_xy_yaw: tuple[float, float, float], fused_mask: np.ndarray | None
) -> dict[str, pa.Table]:
    """One keyframe's infer inputs for the L object seen from a planar sonar pose."""
    pts, _ = _l_object()
    x0, y0, yaw = pose_xy_yaw
    c, s = np.cos(yaw), np.sin(yaw)
    d = pts - [x0, y0, 0.0]
    p = np.c_[c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]]  # sonar frame
    r = np.linalg.norm(p, axis=1)
    b = np.arctan2(p[:, 1], p[:, 0])
    n = r.size
    fid = np.arange(n, dtype=np.int64)
    out = {
        "objects": pa.table(
            {
                "keyframe_id": [kf],
                "object_id": [0],
                "class_name": ["cylindrical_piling"],
                "probability": [1.0],
                "n_features": [n],
            }
        ),
        "object_features": pa.table(
            {"keyframe_id": np.full(n, kf), "object_id": np.zeros(n, np.int64), "feature_id": fid}
        ),
        "features": pa.table(
            {
                "keyframe_id": np.full(n, kf),
                "feature_id": fid,
                "sonar": ["horizontal"] * n,
                "range_m": r,
                "angle_rad": b,
            }
        ),
    }
    m = np.zeros(n, bool) if fused_mask is None else fused_mask
    el = np.arcsin(p[m, 2] / r[m])
    out["fused"] = pa.table(
        {
            "keyframe_id": np.full(m.sum(), kf),
            "feature_id_horizontal": fid[m],
            "range_m": r[m],
            "bearing_rad": b[m],
            "elevation_rad": el,
            "x_m": p[m, 0],
            "y_m": p[m, 1],
            "z_m": p[m, 2],
            "confidence": np.ones(m.sum()),
        }
    )
    return out


def _concat(parts: list[dict[str, pa.Table]]) -> dict[str, pa.Table]:
    return {k: pa.concat_tables([p[k] for p in parts]) for k in parts[0]}


def _asymmetric_mission() -> dict[str, pa.Table]:
    """kf 0 and 1 fuse the right and the left part of the object from different poses,
    kf 2 sees it from a third pose (at a negative bearing) with no fused point."""
    pts, _ = _l_object()
    right, left = pts[:, 1] < 0.15, pts[:, 1] > -0.15
    return _concat(
        [
            _sighting(0, (0.0, 0.0, np.deg2rad(-25.0)), right),
            _sighting(1, (1.0, 0.3, np.deg2rad(20.0)), left),
            _sighting(2, (-0.5, 0.0, np.deg2rad(35.0)), None),
        ]
    )


def _sign_agreement(points: pa.Table, keyframe_id: int) -> tuple[float, int]:
    """Fraction of inferred points of a keyframe with the true height sign, and count."""
    sel = points.filter(
        pa.compute.and_(
            pa.compute.equal(points.column("source"), "inferred"),
            pa.compute.equal(points.column("keyframe_id"), keyframe_id),
        )
    )
    _, z_true = _l_object()
    inputs = _asymmetric_mission()
    feats = inputs["features"].filter(
        pa.compute.equal(inputs["features"].column("keyframe_id"), keyframe_id)
    )
    b_all = feats.column("angle_rad").to_numpy()
    r_all = feats.column("range_m").to_numpy()
    # match each inferred point to its feature by (range, bearing) of the correct geometry
    idx = np.array(
        [
            int(np.argmin(np.abs(r_all - r) + np.abs(b_all - b)))
            for r, b in zip(
                sel.column("range_m").to_numpy(), sel.column("bearing_rad").to_numpy(), strict=True
            )
        ]
    )
    agree = (
        np.sign(sel.column("z_m").to_numpy()) == np.sign(z_true[idx]) if idx.size else np.array([])
    )
    return float(np.mean(agree)) if idx.size else 0.0, int(idx.size)


def test_asymmetric_object_from_other_bearings_gets_the_right_heights() -> None:
    inputs = _asymmetric_mission()
    points = infer_points(
        inputs["objects"],
        inputs["object_features"],
        inputs["features"],
        inputs["fused"],
        InferConfig(),
    )
    agree, n = _sign_agreement(points, 2)
    n_features = int(np.sum(inputs["features"].column("keyframe_id").to_numpy() == 2))
    assert n >= 0.5 * n_features
    assert agree >= 0.95
    z = points.filter(pa.compute.equal(points.column("keyframe_id"), 2)).column("z_m").to_numpy()
    np.testing.assert_allclose(np.abs(z), 0.6, atol=0.1)


def test_final_model_predicts_sightings_from_before_the_first_update() -> None:
    """kf 0 sees the object in 2D only, before anything is learned; kf 1 and 2 fuse it.
    Online (the paper), kf 0 predicts nothing; with the final model it gets the heights
    the later keyframes taught, and the keyframes after the first update lose nothing."""
    pts, _ = _l_object()
    right, left = pts[:, 1] < 0.15, pts[:, 1] > -0.15
    inputs = _concat(
        [
            _sighting(0, (-0.5, 0.0, np.deg2rad(35.0)), None),
            _sighting(1, (0.0, 0.0, np.deg2rad(-25.0)), right),
            _sighting(2, (1.0, 0.3, np.deg2rad(20.0)), left),
        ]
    )

    def inferred(query_model: str) -> pa.Table:
        points = infer_points(
            inputs["objects"], inputs["object_features"], inputs["features"], inputs["fused"],
            InferConfig(query_model=query_model),
        )  # fmt: skip
        return points.filter(pa.compute.equal(points.column("source"), "inferred"))

    online, final = inferred("online"), inferred("final")
    eq = pa.compute.equal
    assert online.filter(eq(online.column("keyframe_id"), 0)).num_rows == 0
    early = final.filter(eq(final.column("keyframe_id"), 0))
    assert early.num_rows >= 0.5 * int(
        np.sum(inputs["features"].column("keyframe_id").to_numpy() == 0)
    )
    np.testing.assert_allclose(np.abs(early.column("z_m").to_numpy()), 0.6, atol=0.1)
    later = [pa.compute.greater(t.column("keyframe_id"), 0) for t in (online, final)]
    assert final.filter(later[1]).num_rows >= online.filter(later[0]).num_rows


def test_unknown_objects_borrow_a_piling_model_only_when_they_register() -> None:
    """`unknown_argmax_classes` with a piling class: kf 2's object, left unknown by the
    classifier with cylindrical_piling as its arg-max, gets that model's heights once it
    registers to the class's reference; the model learns nothing from it, and an unknown
    object of another shape (a 6 m straight wall) does not register and gets none."""
    base = _asymmetric_mission()
    wall = _sighting(3, (0.0, 0.0, 0.0), None)
    r = np.linspace(6.0, 6.2, 60)
    b = np.arctan2(np.linspace(-3.0, 3.0, 60), 6.0)
    wall["features"] = pa.table(
        {"keyframe_id": np.full(60, 3), "feature_id": np.arange(60), "sonar": ["horizontal"] * 60,
         "range_m": r, "angle_rad": b}
    )  # fmt: skip
    wall["object_features"] = pa.table(
        {"keyframe_id": np.full(60, 3), "object_id": np.zeros(60, np.int64), "feature_id": np.arange(60)}
    )  # fmt: skip
    inputs = _concat([base, wall])
    kf = inputs["objects"].column("keyframe_id").to_numpy()
    objects = (
        inputs["objects"]
        .set_column(
            inputs["objects"].schema.get_field_index("class_name"),
            "class_name",
            pa.array(np.where(kf >= 2, "unknown", "cylindrical_piling").tolist()),
        )
        .append_column("argmax_class_name", pa.array(["cylindrical_piling"] * len(kf)))
    )

    def run(config: InferConfig) -> tuple[pa.Table, dict]:
        return infer_mission(
            objects, inputs["object_features"], inputs["features"], inputs["fused"], config
        )

    plain, plain_stats = run(InferConfig())
    lent, lent_stats = run(InferConfig(unknown_argmax_classes=("cylindrical_piling",)))

    def unknown_inferred(points: pa.Table, keyframe_id: int) -> pa.Table:
        c = pa.compute
        return points.filter(
            c.and_(
                c.and_(
                    c.equal(points.column("class_name"), "unknown"),
                    c.equal(points.column("keyframe_id"), keyframe_id),
                ),
                c.equal(points.column("source"), "inferred"),
            )
        )

    assert unknown_inferred(plain, 2).num_rows == 0
    borrowed = unknown_inferred(lent, 2)
    assert borrowed.num_rows >= 0.5 * int(
        np.sum(inputs["features"].column("keyframe_id").to_numpy() == 2)
    )
    np.testing.assert_allclose(np.abs(borrowed.column("z_m").to_numpy()), 0.6, atol=0.1)
    assert unknown_inferred(lent, 3).num_rows == 0  # the wall does not register
    assert (
        lent_stats["classes"]["cylindrical_piling"] == plain_stats["classes"]["cylindrical_piling"]
    )
    assert lent_stats["classes"]["unknown"]["registered_objects"] == 1


def _run_with_bug(monkeypatch: pytest.MonkeyPatch, bug: str) -> pa.Table:
    """Re-introduce one of the original code's frame bugs into the stage's sightings."""
    original = infer_module._sightings

    def buggy(*args: object, **kwargs: object) -> list:
        out = []
        for s in original(*args, **kwargs):
            if bug == "mirrored_query" and s.fused_z_m.size == 0:
                s = replace(s, uv_m=s.uv_m * [1.0, -1.0])
            if bug == "fused_origin" and s.fused_z_m.size:
                r, b = s.range_m[s.is_fused], s.bearing_rad[s.is_fused]
                s = replace(s, fused_uv_m=to_object_frame(r, b, object_origin(r, b)))
            out.append(s)
        return out

    monkeypatch.setattr(infer_module, "_sightings", buggy)
    inputs = _asymmetric_mission()
    return infer_points(
        inputs["objects"],
        inputs["object_features"],
        inputs["features"],
        inputs["fused"],
        InferConfig(),
    )


@pytest.mark.parametrize("bug", ["mirrored_query", "fused_origin"])
def test_the_original_frame_bugs_would_be_caught(monkeypatch: pytest.MonkeyPatch, bug: str) -> None:
    agree, n = _sign_agreement(_run_with_bug(monkeypatch, bug), 2)
    assert n == 0 or agree < 0.9


# ---------------------------------------------------------------------------------------
# Simulated pier: accuracy and coverage against the true mesh.


@pytest.fixture(scope="module")
def pier() -> tuple[SimRun, TruthTables]:
    run = simulate(load_scene(REPO / "configs" / "scenes" / "pier.yaml"), SimConfig(), 0)
    return run, truth_tables(run, keyframe_indices(run, 4.0))


def _infer(tt: TruthTables, config: InferConfig | None = None) -> pa.Table:
    return infer_points(
        tt.objects,
        tt.object_features,
        tt.features,
        tt.fused,
        config or InferConfig(classes=PILING_CLASSES),
    )


def test_pier_inferred_points_are_accurate_and_multiply_coverage(pier) -> None:
    run, tt = pier
    points = _infer(tt)
    inferred = points.filter(pa.compute.equal(points.column("source"), "inferred"))
    fused_world = to_world(tt.fused, tt.T_world_sonar)
    inferred_world = to_world(inferred, tt.T_world_sonar)
    d_fused = np.median(run.world.distance(fused_world))
    d_inferred = np.median(run.world.distance(inferred_world))
    assert inferred.num_rows > 5 * tt.fused.num_rows
    assert d_inferred <= 0.15
    assert d_inferred <= 1.5 * d_fused
    assert n_voxels(np.vstack([fused_world, inferred_world])) >= 5 * n_voxels(fused_world)


def test_pier_output_contract_and_determinism(pier) -> None:
    _, tt = pier
    a, b = _infer(tt), _infer(tt)
    assert a.equals(b)
    assert a.schema.equals(POINTS_SCHEMA)
    kf = a.column("keyframe_id").to_numpy()
    assert np.all(np.diff(kf) >= 0)
    fused = a.filter(pa.compute.equal(a.column("source"), "fused"))
    of_keys = {
        tuple(k)
        for k in np.c_[
            [tt.object_features.column(c).to_numpy() for c in ("keyframe_id", "feature_id")]
        ].T
    }
    fused_keys = np.c_[
        [tt.fused.column(c).to_numpy() for c in ("keyframe_id", "feature_id_horizontal")]
    ].T
    assert fused.num_rows == sum(tuple(k) in of_keys for k in fused_keys)  # fused points on objects
    inferred = a.filter(pa.compute.equal(a.column("source"), "inferred"))
    assert set(inferred.column("class_name").to_pylist()) <= {
        "cylindrical_piling",
        "rectangular_piling",
    }
    # Eq. 1 and the elevation limit of the aperture.
    r, b, e = (inferred.column(c).to_numpy() for c in ("range_m", "bearing_rad", "elevation_rad"))
    np.testing.assert_allclose(inferred.column("x_m").to_numpy(), r * np.cos(e) * np.cos(b))
    np.testing.assert_allclose(inferred.column("z_m").to_numpy(), r * np.sin(e))
    assert np.all(np.abs(e) <= np.deg2rad(10.0) + 1e-12)
    assert np.all(inferred.column("confidence").to_numpy() > InferConfig().confidence_threshold)
    # No prediction before the first keyframe with fused points of the class (time order).
    first_fused = int(fused.column("keyframe_id").to_numpy().min())
    assert int(inferred.column("keyframe_id").to_numpy().min()) >= first_fused
    # At most two points (one per half) per 2D feature.
    keys = np.c_[inferred.column("keyframe_id").to_numpy(), r, b]
    _, counts = np.unique(keys, axis=0, return_counts=True)
    assert counts.max() <= 2


def test_stage_object_runs_from_bound_inputs(pier) -> None:
    _, tt = pier
    out = STAGE.run(
        InferConfig(classes=("rectangular_piling",)),
        {
            "classify.objects": tt.objects,
            "classify.object_features": tt.object_features,
            "features.features": tt.features,
            "fuse.fused": tt.fused,
        },
    )
    points = out["points"]
    inferred = points.filter(pa.compute.equal(points.column("source"), "inferred"))
    assert set(inferred.column("class_name").to_pylist()) <= {"rectangular_piling"}
    assert STAGE.outputs[0].arrow_schema.equals(points.schema)


def real_stage_tables(run: SimRun, spacing_m: float) -> tuple[pa.Table, ...]:
    """(objects, object_features, features, fused) from the real CFAR and fusion stages;
    objects from DBSCAN with their majority true class standing in for the CNN."""
    from sonarmap.schemas.sonar import KeyframeImages
    from sonarmap.stages.classify.objects import extract_objects, horizontal_features
    from sonarmap.stages.features.stage import FeaturesConfig, features_table
    from sonarmap.stages.fuse.stage import FuseConfig, fuse_table

    frames = [
        KeyframeImages(k, f.t_ns, f.horizontal, f.vertical)
        for k, f in enumerate(run.frame(i) for i in keyframe_indices(run, spacing_m))
    ]
    # The fixed front end (floor 20, exponential factor) the inference tests were measured
    # on: with the calibrated one, the coarse-fallback test's pier run finds no seen
    # returns to fill for one class (a follow-up, docs/front-end.md).
    fixed = FeaturesConfig(intensity_floor=20.0, threshold_factor="exponential", denoise="none")
    features = features_table(frames, fixed)
    sensors = {s: {"T_base_sonar": m.tolist()} for s, m in run.T_base_sonar.items()}
    fused = fuse_table(frames, features, sensors, FuseConfig())
    by_kf = horizontal_features(features)
    objects, links = [], []
    for frame in frames:
        f = by_kf.get(frame.keyframe_id)
        if f is None:
            continue
        o = extract_objects(
            frame.horizontal, f["range_bin"], f["beam"], f["range_m"], f["angle_rad"],
            eps_m=0.25, min_samples=2, min_features=10, margin_m=0.2, min_side_m=0.5,
        )  # fmt: skip
        for j in range(o.count):
            ids = f["feature_id"][o.feature_index[o.object_index == j]]
            object_id = len(objects)
            objects.append({"keyframe_id": frame.keyframe_id, "object_id": object_id,
                            "class_name": CLASS_NAMES[o.true_class_id[j]]})  # fmt: skip
            links.append(pa.table({"keyframe_id": np.full(ids.size, frame.keyframe_id),
                                   "object_id": np.full(ids.size, object_id), "feature_id": ids}))  # fmt: skip
    return pa.Table.from_pylist(objects), pa.concat_tables(links), features, fused


@pytest.fixture(scope="module")
def pier_real(pier) -> tuple[pa.Table, ...]:
    return real_stage_tables(pier[0], 4.0)


def test_pier_through_real_features_and_fusion(pier, pier_real) -> None:
    """CFAR features and orthogonal fusion from the real stages (`real_stage_tables`)."""
    run, tt = pier
    objects, links, features, fused = pier_real
    points = infer_points(objects, links, features, fused, InferConfig(classes=PILING_CLASSES))
    inferred = points.filter(pa.compute.equal(points.column("source"), "inferred"))
    fused_world = to_world(fused, tt.T_world_sonar)
    inferred_world = to_world(inferred, tt.T_world_sonar)
    d_fused = np.median(run.world.distance(fused_world))
    d_inferred = np.median(run.world.distance(inferred_world))
    assert inferred.num_rows > fused.num_rows
    assert d_inferred <= 0.15
    assert d_inferred <= 1.5 * d_fused
    assert n_voxels(np.vstack([fused_world, inferred_world])) >= 3 * n_voxels(fused_world)


def test_coarse_fallback_fills_unseen_cells_on_the_true_surface(pier, pier_real) -> None:
    """`coarse_fallback_factor=2`: returns whose model cell is empty take the cell twice
    as large around it; more of the piling is predicted, still on the true mesh."""
    run, tt = pier
    objects, links, features, fused = pier_real

    def inferred_world(factor: int) -> tuple[np.ndarray, dict]:
        config = InferConfig(classes=PILING_CLASSES, coarse_fallback_factor=factor)
        points, stats = infer_mission(objects, links, features, fused, config)
        inferred = points.filter(pa.compute.equal(points.column("source"), "inferred"))
        return to_world(inferred, tt.T_world_sonar), stats

    (plain, plain_stats), (filled, filled_stats) = inferred_world(1), inferred_world(2)
    for c in PILING_CLASSES:
        before, after = plain_stats["classes"][c], filled_stats["classes"][c]
        assert after["queried_returns"] == before["queried_returns"]
        assert after["seen_returns"] > before["seen_returns"]
    d_fused = np.median(run.world.distance(to_world(fused, tt.T_world_sonar)))
    d_plain, d_filled = run.world.distance(plain), run.world.distance(filled)
    assert len(filled) > len(plain)
    assert np.median(d_filled) <= 1.5 * d_fused
    assert np.median(d_filled) <= np.median(d_plain) + 0.02
    assert n_voxels(filled[d_filled <= 0.1]) > n_voxels(plain[d_plain <= 0.1])


def test_config_refuses_unknown_classes_and_keys() -> None:
    # Class names are checked against the run's class table (`classes`), naming it.
    with pytest.raises(
        ValueError, match=r"infer\.classes: unknown class 'pilling'.*classes\.table"
    ):
        InferConfig(classes=("pilling",)).with_table(DEFAULT_TABLE)
    with pytest.raises(ValueError):
        InferConfig(sigma=0.1)
    with pytest.raises(ValueError):
        InferConfig(z_min_m=1.0, z_max_m=-1.0)
