"""The classify stage on simulated keyframes: objects, links to features, truth, determinism."""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
import torch

from sonarmap.schemas.classes import CLASS_IDS, CLASS_NAMES, DEFAULT_TABLE, UNKNOWN_CLASS
from sonarmap.schemas.objects import OBJECT_FEATURES_SCHEMA, OBJECTS_SCHEMA, UNKNOWN_CLASS_ID
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.classify.cnn import PatchCNN, model_to_bytes
from sonarmap.stages.classify.stage import STAGE, ClassifyConfig, keyframe_seed

ROOT = Path(__file__).resolve().parents[1]
NAMES = ["cylindrical_piling", "rectangular_piling", "seafloor"]


@pytest.fixture(scope="module")
def simulated() -> tuple[list[KeyframeImages], pa.Table, dict]:
    """Six keyframes of the tiny scene, their dead-reckoning poses and the sonar mounting."""
    from sonarmap.sim.config import MissionConfig, SimConfig
    from sonarmap.sim.dataset import simulate
    from sonarmap.sim.scene import load_scene

    run = simulate(
        load_scene(ROOT / "configs/scenes/tiny.yaml"),
        SimConfig(mission=MissionConfig(n_goals=2)),
        5,
    )
    out, poses = [], []
    for i in range(0, run.n_frames, 6):
        f = run.frame(i)
        if (f.horizontal.labels > 0).sum() > 50:
            out.append(KeyframeImages(len(out), f.t_ns, f.horizontal, f.vertical))
            poses.append(f.dr_pose)
        if len(out) == 6:
            break
    assert len(out) >= 3
    return out, keyframes_table(out, np.array(poses)), sensors_json(run.T_base_sonar)


@pytest.fixture(scope="module")
def keyframes(simulated: tuple[list[KeyframeImages], pa.Table, dict]) -> list[KeyframeImages]:
    return simulated[0]


def keyframes_table(frames: list[KeyframeImages], dr_pose: np.ndarray) -> pa.Table:
    """The pose columns of keyframes.parquet that classify reads (dead reckoning)."""
    names = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
    return pa.table(
        {
            "keyframe_id": pa.array([fr.keyframe_id for fr in frames], pa.int64()),
            **{n: pa.array(dr_pose[:, i], pa.float64()) for i, n in enumerate(names)},
        }
    )


def sensors_json(T_base_sonar: dict[str, np.ndarray]) -> dict:
    return {k: {"T_base_sonar": np.asarray(v).tolist()} for k, v in T_base_sonar.items()}


def _features(frames: list[KeyframeImages]) -> pa.Table:
    """Features as CFAR would give them: labelled cells plus isolated noise cells."""
    rng = np.random.default_rng(0)
    cols: dict[str, list[np.ndarray]] = {
        k: [] for k in ("keyframe_id", "feature_id", "sonar", "range_bin", "beam")
    }
    for fr in frames:
        h = fr.horizontal
        rb, bm = np.nonzero(h.labels > 0)
        nr, nb = rng.integers(0, h.image.shape[0], 15), rng.integers(0, h.image.shape[1], 15)
        rb, bm = np.concatenate([rb, nr]), np.concatenate([bm, nb])
        n = len(rb)
        cols["keyframe_id"].append(np.full(n + 3, fr.keyframe_id))
        cols["feature_id"].append(np.arange(n + 3) + 100_000 * fr.keyframe_id)
        cols["sonar"].append(np.array(["horizontal"] * n + ["vertical"] * 3))
        cols["range_bin"].append(np.concatenate([rb, [5, 6, 7]]))
        cols["beam"].append(np.concatenate([bm, [5, 6, 7]]))
    out = {k: np.concatenate(v) for k, v in cols.items()}
    h = frames[0].horizontal
    return pa.table(
        {
            **{k: pa.array(v, pa.int64()) for k, v in out.items() if k != "sonar"},
            "sonar": pa.array(out["sonar"]),
            "range_m": h.ranges_m[out["range_bin"]].astype(np.float64),
            "angle_rad": h.angles_rad[out["beam"]].astype(np.float64),
            "intensity": pa.array(np.full(len(out["beam"]), 200, np.uint8)),
        }
    )


def _model_bytes() -> bytes:
    torch.manual_seed(0)
    model = PatchCNN(len(NAMES), (8, 16), 32, 0.2)
    cfg = {
        "channels": [8, 16],
        "hidden": 32,
        "dropout_p": 0.2,
        "size_px": 40,
        "margin_m": 0.2,
        "min_side_m": 0.5,
        "eps_m": 0.25,
        "min_samples": 2,
        "min_features": 10,
    }
    return model_to_bytes(model, NAMES, cfg)


def _run(frames: list[KeyframeImages], features: pa.Table, **cfg: object) -> dict:
    """The stage without multi-view pooling (its own tests are below and in test_train)."""
    torch.set_num_threads(1)
    inputs = {
        "keyframes.frames": frames,
        "features.features": features,
        "train.model": _model_bytes(),
    }
    return dict(STAGE.run(ClassifyConfig(**{"pool_views": False, **cfg}), inputs))


@pytest.mark.usefixtures("no_matplotlib")
def test_objects_link_to_their_features_and_carry_the_majority_truth(
    keyframes: list[KeyframeImages],
) -> None:
    features = _features(keyframes)
    out = _run(keyframes, features, threshold=0.0)
    objects, links = out["objects"], out["object_features"]
    assert objects.schema.equals(OBJECTS_SCHEMA) and links.schema.equals(OBJECT_FEATURES_SCHEMA)
    assert objects.num_rows >= len(keyframes)
    np.testing.assert_array_equal(objects["object_id"].to_numpy(), np.arange(objects.num_rows))
    # Every link points at a horizontal feature of the same keyframe.
    fid = features["feature_id"].to_numpy()
    row_of = {int(v): i for i, v in enumerate(fid)}
    sonar = np.asarray(features["sonar"].to_pylist())
    f_kf, f_rb, f_bm = (features[c].to_numpy() for c in ("keyframe_id", "range_bin", "beam"))
    f_r, f_a = features["range_m"].to_numpy(), features["angle_rad"].to_numpy()
    l_obj, l_kf = links["object_id"].to_numpy(), links["keyframe_id"].to_numpy()
    l_rows = np.array([row_of[int(v)] for v in links["feature_id"].to_numpy()])
    assert (sonar[l_rows] == "horizontal").all()
    np.testing.assert_array_equal(f_kf[l_rows], l_kf)
    # n_features, centroid and true class follow from the linked features and the labels.
    by_kf = {fr.keyframe_id: fr for fr in keyframes}
    for row in objects.to_pylist():
        rows = l_rows[l_obj == row["object_id"]]
        assert len(rows) == row["n_features"] >= 10
        lab = by_kf[row["keyframe_id"]].horizontal.labels[f_rb[rows], f_bm[rows]]
        assert row["true_class_name"] == CLASS_NAMES[np.bincount(lab).argmax()]
        x = f_r[rows] * np.cos(f_a[rows])
        assert row["x_m"] == pytest.approx(x.mean(), abs=1e-9)
        assert row["x_min_m"] == pytest.approx(x.min(), abs=1e-9)
        assert row["class_name"] == row["argmax_class_name"]  # threshold 0 accepts all
        assert row["class_id"] == CLASS_IDS[row["class_name"]]
    # The isolated noise cells never make an object: every object is a labelled target.
    assert set(objects["true_class_name"].to_pylist()) <= {
        "cylindrical_piling",
        "rectangular_piling",
        "seafloor",
    }
    assert "overlay" not in out  # the `figures` stage draws it


def test_the_overlay_draws_the_busiest_keyframe_the_same_every_time(
    keyframes: list[KeyframeImages],
) -> None:
    from sonarmap.stages.figures.overlay import busiest_keyframe, overlay_png

    objects = _run(keyframes, _features(keyframes), threshold=0.0)["objects"]
    chosen, rows = busiest_keyframe(objects)
    kf = objects["keyframe_id"].to_numpy()
    assert rows.num_rows == np.bincount(kf).max() and set(rows["keyframe_id"].to_pylist()) == {
        chosen
    }
    frame = next(f for f in keyframes if f.keyframe_id == chosen)
    png = overlay_png(frame, rows)
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and overlay_png(frame, rows) == png


def test_classify_overlay_is_refused_with_where_it_moved(tmp_path: Path) -> None:
    from sonarmap.pipeline.engine.config.load import load_config
    from sonarmap.pipeline.engine.errors import ConfigError
    from sonarmap.pipeline.graph import all_stages

    config = tmp_path / "old.yaml"
    config.write_text("classify:\n  overlay: false\n")
    for path, overrides in ((config, ()), (None, ("classify.overlay=false",))):
        with pytest.raises(
            ConfigError, match=r"'classify\.overlay' \(moved to 'figures\.overlay'\)"
        ):
            load_config(all_stages(), path, overrides)


def test_uncertain_objects_are_unknown(keyframes: list[KeyframeImages]) -> None:
    objects = _run(keyframes, _features(keyframes), threshold=1.0)["objects"]
    assert objects.num_rows > 0
    assert set(objects["class_name"].to_pylist()) == {UNKNOWN_CLASS}
    assert set(objects["class_id"].to_pylist()) == {UNKNOWN_CLASS_ID}
    assert min(objects["probability"].to_pylist()) > 1.0 / len(NAMES) - 1e-9


def test_same_inputs_same_outputs_and_the_seed_changes_the_masks(
    keyframes: list[KeyframeImages],
) -> None:
    features = _features(keyframes)
    a = _run(keyframes, features)
    b = _run(keyframes, features)
    c = _run(keyframes, features, seed=1)
    assert a["objects"].equals(b["objects"]) and a["object_features"].equals(b["object_features"])
    assert a["objects"]["probability"] != c["objects"]["probability"]
    assert a["objects"]["probability_var"].to_numpy().min() > 0.0


def test_without_labels_truth_is_null_and_without_features_no_objects(
    keyframes: list[KeyframeImages],
) -> None:
    unlabelled = [
        dataclasses.replace(fr, horizontal=dataclasses.replace(fr.horizontal, labels=None))
        for fr in keyframes
    ]
    features = _features(keyframes)
    objects = _run(unlabelled, features)["objects"]
    assert objects.num_rows > 0 and objects["true_class_name"].null_count == objects.num_rows
    empty = _run(keyframes, features.slice(0, 0))
    assert empty["objects"].num_rows == 0 and empty["object_features"].num_rows == 0


def test_bad_model_bytes_are_a_value_error(keyframes: list[KeyframeImages]) -> None:
    inputs = {
        "keyframes.frames": keyframes,
        "features.features": _features(keyframes),
        "train.model": b"xx",
    }
    with pytest.raises(ValueError, match="model"):
        STAGE.run(ClassifyConfig(), inputs)


def test_clustering_comes_from_the_model_and_the_config_overrides_it(
    keyframes: list[KeyframeImages],
) -> None:
    features = _features(keyframes)
    default = _run(keyframes, features, threshold=0.0)["objects"]
    sizes = default["n_features"].to_numpy()
    cut = int(np.median(sizes)) + 1
    stricter = _run(keyframes, features, threshold=0.0, min_features=cut)["objects"]
    assert stricter.num_rows == (sizes >= cut).sum() < default.num_rows
    blob = torch.load(io.BytesIO(_model_bytes()), weights_only=True)
    del blob["config"]["eps_m"]
    buf = io.BytesIO()
    torch.save(blob, buf)
    inputs = {"keyframes.frames": keyframes, "features.features": features}
    with pytest.raises(ValueError, match=r"no 'eps_m'; set classify.eps_m"):
        STAGE.run(ClassifyConfig(pool_views=False), {**inputs, "train.model": buf.getvalue()})
    cfg = ClassifyConfig(eps_m=0.25, pool_views=False)
    assert STAGE.run(cfg, {**inputs, "train.model": buf.getvalue()})


def test_pooling_combines_sightings_of_one_place_and_needs_the_poses(
    simulated: tuple[list[KeyframeImages], pa.Table, dict],
) -> None:
    frames, poses, sensors = simulated
    features = _features(frames)
    inputs = {
        "keyframes.frames": frames,
        "keyframes.keyframes": poses,
        "keyframes.sensors": sensors,
        "features.features": features,
        "train.model": _model_bytes(),
    }
    single = _run(frames, features, threshold=0.0)["objects"]
    pooled = STAGE.run(ClassifyConfig(threshold=0.0), inputs)["objects"]
    assert pooled.equals(STAGE.run(ClassifyConfig(threshold=0.0), inputs)["objects"])
    # Same objects; the single-view columns are this keyframe's, of the pooled argmax class.
    for name in ("object_id", "n_features", "x_m", "true_class_name"):
        assert pooled[name].equals(single[name]), name
    same = np.asarray(pooled["argmax_class_name"].to_pylist()) == np.asarray(
        single["argmax_class_name"].to_pylist()
    )
    assert same.any()
    for mine, theirs in (("single_view_probability", "probability"), ("probability_var",) * 2):
        np.testing.assert_array_equal(
            pooled[mine].to_numpy()[same], single[theirs].to_numpy()[same]
        )
    n_views = pooled["n_views"].to_numpy()
    # The tiny scene's pilings are seen from every keyframe, a few metres apart.
    assert (n_views > 1).mean() > 0.5 and n_views.max() <= len(frames)
    alone = n_views == 1
    np.testing.assert_allclose(
        pooled["probability"].to_numpy()[alone], single["probability"].to_numpy()[alone]
    )
    assert not np.allclose(pooled["probability"].to_numpy(), single["probability"].to_numpy())
    # A zero radius pools nothing.
    lone = STAGE.run(ClassifyConfig(threshold=0.0, pool_radius_m=1e-9), inputs)
    none = lone["objects"]
    assert set(none["n_views"].to_pylist()) == {1}
    # ... so no object of a compact class (a piling: min_views 2) is accepted, and the
    # acceptance report counts them; a wall's class still is.
    kinds = DEFAULT_TABLE.frame_kinds()
    held = [kinds.get(n) == "object" for n in none["argmax_class_name"].to_pylist()]
    names = none["class_name"].to_pylist()
    assert any(held) and all(n == "unknown" for n, h in zip(names, held, strict=True) if h)
    assert all(n != "unknown" for n, h in zip(names, held, strict=True) if not h)
    assert lone["acceptance"]["unconfirmed"] == sum(held)
    assert lone["acceptance"]["min_views"] == 2 and lone["acceptance"]["min_seen_share"] == 0.0
    # The tiny scene's pilings are seen by the keyframes whose fans cover them, so the
    # opt-in share rule keeps every piling the default keeps.
    share = STAGE.run(ClassifyConfig(threshold=0.0, min_seen_share=0.5), inputs)
    assert share["objects"]["class_name"].equals(pooled["class_name"])
    without = {k: v for k, v in inputs.items() if k != "keyframes.keyframes"}
    with pytest.raises(ValueError, match="pool_views needs"):
        STAGE.run(ClassifyConfig(), without)


# --- The original's protocol: single view at 0.99, minimum area, fan edge --------------


def _confident_model_bytes(scale: float = 30.0, bias: float = 5.5) -> bytes:
    """The test model with its output layer scaled and class 0 favoured, so that the mean
    of 20 MC-dropout passes straddles 0.99 over the tiny scene's objects."""
    blob = torch.load(io.BytesIO(_model_bytes()), weights_only=True)
    model = PatchCNN(len(NAMES), (8, 16), 32, 0.2)
    model.load_state_dict(blob["state_dict"])
    with torch.no_grad():
        model.fc2.weight *= scale
        model.fc2.bias[0] += bias
    return model_to_bytes(model, blob["class_names"], blob["config"])


def test_single_view_rule_accepts_the_mean_of_m_passes_above_0_99(
    simulated: tuple[list[KeyframeImages], pa.Table, dict],
) -> None:
    """The paper's rule (pool_views false): each sighting on its own, accepted when the mean
    of m = 20 MC-dropout softmax outputs exceeds 0.99. Observed: 6 of 12 accepted."""
    from sonarmap.stages.classify.cnn import mc_predict_groups, model_from_bytes
    from sonarmap.stages.classify.objects import extract_objects, horizontal_features

    frames, poses, sensors = simulated
    features = _features(frames)
    model_bytes = _confident_model_bytes()
    inputs = {
        "keyframes.frames": frames,
        "keyframes.keyframes": poses,
        "keyframes.sensors": sensors,
        "features.features": features,
        "train.model": model_bytes,
    }
    torch.set_num_threads(1)
    cfg = ClassifyConfig(pool_views=False, threshold=0.99, mc_passes=20)
    objects = STAGE.run(cfg, inputs)["objects"]
    p = objects["probability"].to_numpy()
    accepted = objects["class_id"].to_numpy() != UNKNOWN_CLASS_ID
    assert 0 < accepted.sum() < objects.num_rows
    np.testing.assert_array_equal(accepted, p > 0.99)
    np.testing.assert_array_equal(p, objects["single_view_probability"].to_numpy())
    assert set(objects["n_views"].to_pylist()) == {1}
    names = np.asarray(objects["class_name"].to_pylist())
    argmax = np.asarray(objects["argmax_class_name"].to_pylist())
    assert (names[accepted] == argmax[accepted]).all() and (names[~accepted] == UNKNOWN_CLASS).all()
    # probability is this keyframe's own mean over m = 20 passes of its patch, whatever
    # the other keyframes batched with it (up to float32 rounding of the batched products).
    model, _, mcfg = model_from_bytes(model_bytes)
    by_kf = horizontal_features(features)
    kf = objects["keyframe_id"].to_numpy()
    for fr in frames:
        f = by_kf[fr.keyframe_id]
        objs = extract_objects(
            fr.horizontal, f["range_bin"], f["beam"], f["range_m"], f["angle_rad"],
            eps_m=0.25, min_samples=2, min_features=10, margin_m=mcfg["margin_m"],
            min_side_m=mcfg["min_side_m"], size_px=40,
        )  # fmt: skip
        seed = keyframe_seed(cfg.seed, fr.t_ns)
        mean, _ = mc_predict_groups(model, objs.patches, [objs.count], [seed], 20)
        np.testing.assert_allclose(mean.max(axis=1), p[kf == fr.keyframe_id], rtol=1e-7)
    # Pooling over views (the default) decides differently on the same sightings.
    pooled = STAGE.run(ClassifyConfig(threshold=0.99), inputs)["objects"]
    assert not np.array_equal(pooled["probability"].to_numpy(), p)


def test_min_area_rule_keeps_exactly_the_objects_covering_more(
    keyframes: list[KeyframeImages],
) -> None:
    """Area = fan-plane area of the object's cells (stages.classify.segmentation.cell_areas_m2), checked
    against a 1 cm raster of those cells. Observed on the tiny scene (features = labelled
    cells): cylindrical pilings 0.11-0.24 m2 (dropped at the original's 150 px = 0.375 m2),
    rectangular 0.42-0.61 m2; the two measures agree to 0.004 m2."""
    from test_objects import covered_area_m2

    features = _features(keyframes)
    every = _run(keyframes, features, threshold=0.0)
    big = _run(keyframes, features, threshold=0.0, min_object_area_m2=0.375)
    objects, links = every["objects"], every["object_features"]
    rows = {int(v): i for i, v in enumerate(features["feature_id"].to_numpy())}
    rb, bm = features["range_bin"].to_numpy(), features["beam"].to_numpy()
    by_kf = {fr.keyframe_id: fr.horizontal for fr in keyframes}
    areas = []
    for oid, kf in zip(
        objects["object_id"].to_pylist(), objects["keyframe_id"].to_pylist(), strict=True
    ):
        fid = links["feature_id"].to_numpy()[links["object_id"].to_numpy() == oid]
        r = np.array([rows[int(v)] for v in fid])
        h = by_kf[kf]
        areas.append(covered_area_m2(h.ranges_m, h.angles_rad, rb[r], bm[r], 0.01))
    area = np.array(areas)
    keep = area > 0.375
    assert 0 < keep.sum() < len(keep)
    assert np.all(np.abs(area - 0.375) > 0.03)  # no object on the edge of the rule
    # Exactly the larger objects remain, unchanged but renumbered; their links follow (the
    # probabilities differ: a keyframe's dropout masks are drawn for its whole batch).
    for name in ("keyframe_id", "n_features", "x_m", "y_m", "true_class_name"):
        assert big["objects"][name].to_pylist() == [
            v for v, k in zip(objects[name].to_pylist(), keep, strict=True) if k
        ], name
    np.testing.assert_array_equal(big["objects"]["object_id"].to_numpy(), np.arange(keep.sum()))
    kept_ids = objects["object_id"].to_numpy()[keep]
    want = links.filter(pa.compute.is_in(links["object_id"], pa.array(kept_ids)))
    assert big["object_features"]["feature_id"].equals(want["feature_id"])
    assert set(big["objects"]["true_class_name"].to_pylist()) == {"rectangular_piling"}


FAN_EDGE_PILINGS = (
    # sonar-frame (range m, bearing deg); radius 0.3 m. Those whose disc crosses the
    # +-65 deg fan edge (|bearing| + asin(0.3 / range) > 65 deg) touch it.
    (10.0, 0.0),
    (12.0, 50.0),
    (8.0, 64.8),
    (15.0, -65.0),
    (27.0, 15.0),
    (6.0, -35.0),
    (20.0, -64.5),
)


def test_fan_edge_rule_drops_exactly_the_sightings_of_pilings_cut_by_the_fan() -> None:
    """Two keyframes of a scene with pilings inside the fan and across its edges; CFAR
    features (defaults). Observed: 14 objects, the 6 sightings of the three edge pilings
    dropped. (A piling across the 30 m arc gives no features at all: SOCA-CFAR cannot test
    the last 15 bins, so it is not in the scene.)"""
    from sonarmap.sim.config import SimConfig
    from sonarmap.sim.dataset import SimRun
    from sonarmap.sim.scene import Scene
    from sonarmap.sim.world import World
    from sonarmap.stages.features.stage import FeaturesConfig, features_table

    mount = SimConfig().horizontal.mounting.translation_m
    objs = [
        {
            "class": "cylindrical_piling",
            "name": f"p{n}",
            "position_m": [mount[0] + r * np.cos(np.deg2rad(b)), r * np.sin(np.deg2rad(b))],
            "radius_m": 0.3,
        }
        for n, (r, b) in enumerate(FAN_EDGE_PILINGS)
    ]
    scene = Scene.model_validate(
        {
            "name": "fan-edge",
            "seafloor_depth_m": 12.0,
            "area_m": [-40, 40, -40, 40],
            "objects": objs,
        }
    )
    gt = np.zeros((2, 6))
    gt[:, 2] = -2.0
    gt[1, 0] = 0.02
    traj = {"t_ns": np.arange(2, dtype=np.int64) * 500_000_000, "gt_pose": gt, "dr_pose": gt}
    run = SimRun(world=World(scene), config=SimConfig(), seed=3, trajectory=traj, path=None)  # type: ignore[arg-type]
    frames = [KeyframeImages(f.index, f.t_ns, f.horizontal, f.vertical) for f in run.frames()]
    features = features_table(frames, FeaturesConfig())
    every = _run(frames, features, threshold=0.0)
    kept = _run(frames, features, threshold=0.0, drop_fan_edge_objects=True)

    def piling_of(objects: pa.Table) -> np.ndarray:
        """Index of the scene piling nearest each object (sonar frame: the pose moves 2 cm)."""
        xy = np.stack([objects["x_m"].to_numpy(), objects["y_m"].to_numpy()], axis=1)
        true = np.array(
            [[r * np.cos(np.deg2rad(b)), r * np.sin(np.deg2rad(b))] for r, b in FAN_EDGE_PILINGS]
        )
        d = np.linalg.norm(xy[:, None] - true[None], axis=2)
        assert d.min(axis=1).max() < 0.6  # every object is one piling's sighting
        return d.argmin(axis=1)

    edge = {
        n
        for n, (r, b) in enumerate(FAN_EDGE_PILINGS)
        if abs(b) + np.rad2deg(np.arcsin(0.3 / r)) > 65.0
    }
    seen = piling_of(every["objects"])
    assert set(seen.tolist()) == set(range(len(FAN_EDGE_PILINGS)))  # each piling is found
    want = [n not in edge for n in seen]
    assert sum(want) < len(want)
    got = piling_of(kept["objects"])
    assert got.tolist() == seen[want].tolist()
    for name in ("keyframe_id", "n_features", "x_m", "range_m", "bearing_rad"):
        assert kept["objects"][name].to_pylist() == [
            v for v, w in zip(every["objects"][name].to_pylist(), want, strict=True) if w
        ], name

    def linked(links: pa.Table, ids: np.ndarray | None = None) -> set[tuple[int, int]]:
        m = (
            np.ones(links.num_rows, bool)
            if ids is None
            else np.isin(links["object_id"].to_numpy(), ids)
        )
        kf, fid = links["keyframe_id"].to_numpy()[m], links["feature_id"].to_numpy()[m]
        return set(zip(kf.tolist(), fid.tolist(), strict=True))

    # The dropped objects' features are linked to no object.
    dropped_ids = every["objects"]["object_id"].to_numpy()[~np.array(want)]
    dropped = linked(every["object_features"], dropped_ids)
    assert dropped and not linked(kept["object_features"]) & dropped
    assert linked(kept["object_features"]) == linked(every["object_features"]) - dropped


def test_the_ground_truth_oracle_labels_every_object_with_its_true_class(
    keyframes: list[KeyframeImages],
) -> None:
    """`labels="ground_truth"`: the ablation that shows what perfect classification
    would give; certain, no CNN; refused on a recording without label images."""
    features = _features(keyframes)
    objects = _run(keyframes, features, labels="ground_truth")["objects"]
    truth = objects["true_class_name"].to_pylist()
    assert objects.num_rows > 0 and None not in truth
    expected = [t if t in NAMES else UNKNOWN_CLASS for t in truth]
    assert objects["class_name"].to_pylist() == expected
    assert set(objects["probability"].to_pylist()) == {1.0}
    cnn = _run(keyframes, features)["objects"]
    assert cnn["object_id"].equals(objects["object_id"])  # same objects, other classes
    unlabelled = [
        dataclasses.replace(fr, horizontal=dataclasses.replace(fr.horizontal, labels=None))
        for fr in keyframes
    ]
    with pytest.raises(ValueError, match=r"classify\.labels=ground_truth: keyframe 0 has no label"):
        _run(unlabelled, features, labels="ground_truth")


def test_classify_from_work_units_equals_computed_and_reuses_every_keyframe(
    keyframes: list[KeyframeImages],
) -> None:
    """A keyframe's objects and beliefs are cached per keyframe (issue 53): assembled from
    the units, the outputs are the same bytes; a longer run reuses the shorter's units."""
    from tests.test_work_units import _DictUnits

    memo = _DictUnits()
    features = _features(keyframes)
    torch.set_num_threads(1)
    inputs = {"features.features": features, "train.model": _model_bytes()}
    short = {**inputs, "keyframes.frames": keyframes[:-1], "units": memo}
    cfg = ClassifyConfig(pool_views=False)
    first = STAGE.run(cfg, short)
    assert (len(memo.data), memo.hits) == (len(keyframes) - 1, 0)
    again = STAGE.run(cfg, {**inputs, "keyframes.frames": keyframes, "units": memo})
    assert memo.hits == len(keyframes) - 1 and len(memo.data) == len(keyframes)
    plain = STAGE.run(cfg, {**inputs, "keyframes.frames": keyframes})
    for name in ("objects", "object_features"):
        assert again[name].equals(plain[name])
    n_short = first["objects"].num_rows
    assert first["objects"].equals(plain["objects"].slice(0, n_short))
    # The decision after pooling (threshold, pooling, min_seen_share) is not in a unit's
    # key: a sweep over it reuses every keyframe's CNN work.
    hits = memo.hits
    decided = ClassifyConfig(pool_views=False, threshold=0.5, min_views=3, min_seen_share=0.9)
    STAGE.run(decided, {**inputs, "keyframes.frames": keyframes, "units": memo})
    assert memo.hits == hits + len(keyframes) and len(memo.data) == len(keyframes)


class _MemoUnits:
    """An in-memory per-keyframe memo (the engine's `Units`)."""

    def __init__(self) -> None:
        self.data: dict[str, dict[str, np.ndarray]] = {}

    def get(self, key: str) -> dict[str, np.ndarray] | None:
        return self.data.get(key)

    def put(self, key: str, arrays: dict[str, np.ndarray]) -> None:
        self.data[key] = {k: np.array(v) for k, v in arrays.items()}


def _settings() -> dict:
    from sonarmap.stages.classify.cnn import model_from_bytes

    _, names, cfg = model_from_bytes(_model_bytes())
    return {"class_names": names, "config": cfg}


def test_a_run_whose_keyframes_are_all_cached_units_never_loads_the_cnn(
    keyframes: list[KeyframeImages], monkeypatch: pytest.MonkeyPatch
) -> None:
    from sonarmap.stages.base import UNITS_INPUT
    from sonarmap.stages.classify import stage

    loaded: list[stage.LazyModel] = []
    call = stage.LazyModel.__call__

    def spy(self: stage.LazyModel) -> PatchCNN:
        loaded.append(self)
        return call(self)

    monkeypatch.setattr(stage.LazyModel, "__call__", spy)
    memo = _MemoUnits()
    inputs = {
        "keyframes.frames": keyframes,
        "features.features": _features(keyframes),
        "train.model": _model_bytes(),
        "train.settings": _settings(),
        UNITS_INPUT: memo,
    }
    cfg = ClassifyConfig(pool_views=False, threshold=0.0)
    first = dict(STAGE.run(cfg, inputs))
    assert loaded and len(memo.data) == len(keyframes)
    loaded.clear()
    again = dict(STAGE.run(cfg, inputs))  # every keyframe a unit: no torch work at all
    assert loaded == []
    assert again["objects"].equals(first["objects"])
    # without settings.json (a model trained before it existed) the model file says
    old = dict(STAGE.run(cfg, {**inputs, "train.settings": None}))
    assert old["objects"].equals(first["objects"]) and len(loaded) == 1


def test_a_settings_file_that_disagrees_with_its_model_is_refused(
    keyframes: list[KeyframeImages],
) -> None:
    from sonarmap.stages.base import StageInputError

    wrong = _settings()
    wrong["class_names"] = list(reversed(wrong["class_names"]))
    inputs = {
        "keyframes.frames": keyframes,
        "features.features": _features(keyframes),
        "train.model": _model_bytes(),
        "train.settings": wrong,
    }
    with pytest.raises(StageInputError, match=r"differ from its settings\.json"):
        STAGE.run(ClassifyConfig(pool_views=False), inputs)
