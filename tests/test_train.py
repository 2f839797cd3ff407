"""Classifier training: augmentation, leak-free split, and accuracy on an unseen scene."""

from __future__ import annotations

import io
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
import torch

from sonarmap.schemas.classes import CLASS_IDS, PILING_CLASSES, UNKNOWN_CLASS
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.classify.stage import STAGE as CLASSIFY
from sonarmap.stages.classify.stage import ClassifyConfig
from sonarmap.stages.classify.train import STAGE as TRAIN
from sonarmap.stages.classify.train import (
    Samples,
    TrainConfig,
    augment,
    features_from_labels,
    split_train_val,
)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def _one_thread() -> None:
    torch.set_num_threads(1)


def _simulated(
    scene: str, seed: int, goals: int, stride: int, limit: int
) -> tuple[list[KeyframeImages], pa.Table, dict]:
    """Every stride-th ping as a keyframe, with keyframes.parquet's dead-reckoning pose
    columns and sensors.json's mountings (what classify's view pooling reads)."""
    from sonarmap.sim.config import MissionConfig, SimConfig
    from sonarmap.sim.dataset import simulate
    from sonarmap.sim.scene import load_scene

    run = simulate(
        load_scene(ROOT / f"configs/scenes/{scene}.yaml"),
        SimConfig(mission=MissionConfig(n_goals=goals)),
        seed,
    )
    out, poses = [], []
    for i in range(0, run.n_frames, stride):
        f = run.frame(i)
        out.append(KeyframeImages(len(out), f.t_ns, f.horizontal, f.vertical))
        poses.append(f.dr_pose)
        if len(out) == limit:
            break
    names = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
    table = pa.table(
        {
            "keyframe_id": pa.array(np.arange(len(out)), pa.int64()),
            **{n: pa.array(np.asarray(poses)[:, i], pa.float64()) for i, n in enumerate(names)},
        }
    )
    sensors = {k: {"T_base_sonar": np.asarray(v).tolist()} for k, v in run.T_base_sonar.items()}
    return out, table, sensors


def _keyframes(scene: str, seed: int, goals: int, stride: int, limit: int) -> list[KeyframeImages]:
    return _simulated(scene, seed, goals, stride, limit)[0]


def _label_features(frames: list[KeyframeImages]) -> pa.Table:
    parts = []
    for fr in frames:
        f = features_from_labels(fr)
        n = len(f["feature_id"])
        parts.append(
            pa.table(
                {
                    "keyframe_id": pa.array(np.full(n, fr.keyframe_id), pa.int64()),
                    "feature_id": pa.array(
                        f["feature_id"] + 1_000_000 * fr.keyframe_id, pa.int64()
                    ),
                    "sonar": pa.array(["horizontal"] * n, pa.string()),
                    "range_bin": pa.array(f["range_bin"], pa.int64()),
                    "beam": pa.array(f["beam"], pa.int64()),
                    "range_m": f["range_m"],
                    "angle_rad": f["angle_rad"],
                }
            )
        )
    return pa.concat_tables(parts)


def test_augment_is_identity_without_noise_flips_or_rotation() -> None:
    x = torch.rand(6, 1, 40, 40)
    cfg = TrainConfig(noise_std=0.0, flips=False, max_rotation_deg=0.0)
    out = augment(x, cfg, torch.Generator().manual_seed(0))
    torch.testing.assert_close(out, x, atol=1e-5, rtol=0)


def test_augment_flips_mirror_left_right_and_keep_range() -> None:
    x = torch.zeros(64, 1, 40, 40)
    x[:, 0, 5:35, 2:8] = 1.0  # a bar at the left edge
    out = augment(
        x, TrainConfig(noise_std=0.0, max_rotation_deg=0.0), torch.Generator().manual_seed(0)
    )
    left = out[:, 0, :, :20].sum(dim=(1, 2))
    right = out[:, 0, :, 20:].sum(dim=(1, 2))
    flipped = right > left
    assert 10 < int(flipped.sum()) < 54  # about half are mirrored
    torch.testing.assert_close(out[flipped], torch.flip(x[flipped], dims=[3]), atol=1e-5, rtol=0)
    noisy = augment(x, TrainConfig(), torch.Generator().manual_seed(1))
    assert float(noisy.min()) >= 0.0 and float(noisy.max()) <= 1.0


def test_split_never_puts_a_keyframe_on_both_sides_and_keeps_a_guard_gap() -> None:
    kf = np.repeat(np.arange(200), 3)
    s = Samples(
        np.zeros((len(kf), 40, 40), np.float32),
        np.ones(len(kf), np.int64),
        kf,
        np.zeros(len(kf), np.int64),
    )
    cfg = TrainConfig(val_block_keyframes=10, val_every_blocks=5, guard_keyframes=3)
    train, val = split_train_val(s, cfg)
    assert not (train & val).any()
    val_kf, train_kf = np.unique(kf[val]), np.unique(kf[train])
    assert len(val_kf) == 40  # 4 of every 20 blocks... 1 of 5 blocks of 10
    gap = np.abs(train_kf[:, None] - val_kf[None, :]).min()
    assert gap == 4  # 3 guard keyframes dropped between the sides
    two = Samples(s.patches, s.class_id, kf, (kf >= 150).astype(np.int64))
    train2, val2 = split_train_val(two, TrainConfig(split="dataset"))
    np.testing.assert_array_equal(val2, kf >= 150)
    np.testing.assert_array_equal(train2, kf < 150)


@pytest.fixture(scope="module")
def trained() -> dict:
    frames = _keyframes("marina", 1, 6, 6, 72)
    # A small, fast model. On 72 keyframes and 20 epochs the paper's stronger augmentation
    # regularises (recall at 0.8: 0.86 vs 0.81 with the defaults tuned for the full set).
    # No noisy sensor copies: they would make this fixture 4x slower; what they buy is
    # measured by benchmarks/bench_sensor_shift.py.
    cfg = TrainConfig(
        epochs=20, channels=(16, 32), hidden=64, noise_std=0.05, max_rotation_deg=20,
        val_block_keyframes=10, sensor_copies=0,
    )  # fmt: skip
    t0 = time.perf_counter()
    out = dict(
        TRAIN.run(cfg, {"keyframes.frames": frames, "features.features": _label_features(frames)})
    )
    out["seconds"] = time.perf_counter() - t0
    return out


def test_training_writes_a_weights_only_model_metrics_and_a_png(trained: dict) -> None:
    blob = torch.load(io.BytesIO(trained["model"]), weights_only=True)
    assert set(PILING_CLASSES) <= set(blob["class_names"])
    assert blob["config"]["size_px"] == 40 and "state_dict" in blob
    m = trained["metrics"]
    k = len(blob["class_names"])
    assert np.asarray(m["confusion"]).shape == (k, k) and np.sum(m["confusion"]) == m["n"] > 0
    assert m["accuracy"] > 0.6
    assert trained["confusion"][:8] == b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def unseen_pier() -> dict:
    """classify's inputs but the model: 40 keyframes of pier seed 2, features from labels."""
    frames, poses, sensors = _simulated("pier", 2, 4, 5, 40)
    return {
        "keyframes.frames": frames,
        "keyframes.keyframes": poses,
        "keyframes.sensors": sensors,
        "features.features": _label_features(frames),
    }


def test_classifier_is_accurate_on_an_unseen_scene_and_seed(
    trained: dict, unseen_pier: dict
) -> None:
    """Trained on the marina (seed 1), evaluated on the pier (seed 2) through the classify
    stage. This fast model (72 keyframes, 20 epochs) is less confident than the default
    one, so recall is asserted for its argmax and at a lower acceptance threshold; the
    default model's figures at 0.99 come from benchmarks/bench_classify.py."""
    inputs = {**unseen_pier, "train.model": trained["model"]}
    objects = CLASSIFY.run(ClassifyConfig(pool_views=False), inputs)["objects"]
    pred = np.asarray(objects["class_name"].to_pylist())
    argmax = np.asarray(objects["argmax_class_name"].to_pylist())
    truth = np.asarray(objects["true_class_name"].to_pylist())
    prob = objects["probability"].to_numpy()
    assert (truth == "cylindrical_piling").sum() >= 50
    assert set(objects["class_id"].to_pylist()) <= {-1, *CLASS_IDS.values()}
    np.testing.assert_array_equal(pred == UNKNOWN_CLASS, prob <= 0.99)
    pilings = np.isin(truth, PILING_CLASSES)
    assert (argmax[pilings] == truth[pilings]).mean() >= 0.8
    for threshold in (0.99, 0.9, 0.8):
        accepted = prob > threshold
        for name in PILING_CLASSES:
            sel = accepted & (argmax == name)
            if sel.sum() >= 5:
                assert (truth[sel] == name).mean() >= 0.95, (threshold, name)
    recall_08 = (prob[pilings] > 0.8) & (argmax[pilings] == truth[pilings])
    print(
        "fast model:",
        trained["seconds"],
        "s; piling recall at 0.8:",
        recall_08.mean(),
        "at 0.99:",
        (pred[pilings] == truth[pilings]).mean(),
    )
    assert recall_08.mean() >= 0.8


def test_pooling_views_raises_recall_without_losing_precision(
    trained: dict, unseen_pier: dict
) -> None:
    """classify's multi-view pooling on the unseen pier: every piling is seen from several
    keyframes, some close up, and the pooled decision accepts more pilings and stays
    precise. The pool is a weighted geometric mean, a consensus: it lifts objects whose
    typical view clears the threshold. This fast model's views of pilings sit around
    0.8-0.95 (at 0.99 it accepts 4 %), so it is tested at 0.8; the default model at 0.99 on
    full missions is in benchmarks/bench_classify.py."""
    inputs = {**unseen_pier, "train.model": trained["model"]}
    cfg = ClassifyConfig(threshold=0.8)
    single = CLASSIFY.run(cfg.model_copy(update={"pool_views": False}), inputs)["objects"]
    pooled = CLASSIFY.run(cfg, inputs)["objects"]
    truth = np.asarray(pooled["true_class_name"].to_pylist())
    pilings = np.isin(truth, PILING_CLASSES)
    recall = {}
    for label, objects in (("single", single), ("pooled", pooled)):
        pred = np.asarray(objects["class_name"].to_pylist())
        recall[label] = (pred[pilings] == truth[pilings]).mean()
        for name in PILING_CLASSES:
            if (pred == name).sum() >= 5:
                assert (truth[pred == name] == name).mean() >= 0.95, (label, name)
    print("piling recall at 0.8, single view / pooled:", recall)
    assert np.median(pooled["n_views"].to_numpy()) >= 3
    assert recall["pooled"] >= recall["single"] + 0.05


def test_held_out_datasets_validate_and_the_size_rule_curve_is_saved() -> None:
    from sonarmap.stages.classify.train import collect_samples, train_classifier

    worlds = [_keyframes("tiny", seed, 2, 6, 8) for seed in (21, 22, 23, 24)]
    pairs = [(frames, _label_features(frames)) for frames in worlds]
    cfg = TrainConfig(epochs=2, min_class_samples=1, mc_passes=2, grow_step_datasets=1)
    out = train_classifier(pairs[:3], cfg, heldout=pairs[3:])
    m = out["metrics"]
    # Validation is the held-out world's objects (of learned classes), not a keyframe block.
    n_val = len(collect_samples(pairs[3:], cfg).class_id)
    assert 0.9 * n_val <= m["n"] <= n_val and m["n"] > 0
    curve = m["size_rule"]
    sizes = [p["datasets"] for p in curve["points"]]
    assert sizes == list(range(1, len(sizes) + 1)) and curve["chosen_datasets"] in sizes
    assert all(0 <= p["macro_f1"] <= 1 for p in curve["points"])
    assert out["curve"][:8] == b"\x89PNG\r\n\x1a\n"
    assert any(o.name == "curve" and o.filename == "size_curve.png" for o in TRAIN.outputs)


def test_epochs_are_cut_to_the_presentation_budget() -> None:
    from sonarmap.stages.classify.train import epochs_for

    cfg = TrainConfig()
    # The hand-written default set (1,209 samples) keeps its 120 epochs: its model is unchanged.
    assert epochs_for(1209, cfg) == 120
    assert epochs_for(5000, cfg) == 30  # 150,000 // 5,000
    assert epochs_for(10**6, cfg) == 1  # never fewer than one pass
    assert epochs_for(10, TrainConfig(epochs=3)) == 3


def test_noisy_sensor_copies_are_seeded_and_show_the_same_objects() -> None:
    """`train.sensor_copies`: every keyframe's objects again, through other noise floors;
    the same bytes run to run (the model stays reproducible)."""
    from sonarmap.stages.classify.train import collect_samples

    frames = _keyframes("tiny", 21, 2, 6, 4)
    pairs = [(frames, _label_features(frames))]
    clean = collect_samples(pairs, TrainConfig(sensor_copies=0))
    a = collect_samples(pairs, TrainConfig(sensor_copies=2))
    b = collect_samples(pairs, TrainConfig(sensor_copies=2))
    assert len(clean.class_id) > 0
    np.testing.assert_array_equal(a.patches, b.patches)
    np.testing.assert_array_equal(np.sort(a.class_id), np.sort(np.repeat(clean.class_id, 3)))
    np.testing.assert_array_equal(np.unique(a.keyframe_id), np.unique(clean.keyframe_id))
    k = np.sum(clean.keyframe_id == clean.keyframe_id[0])
    np.testing.assert_array_equal(a.patches[:k], clean.patches[:k])  # copy 0 is the clean one
    assert not np.array_equal(a.patches[k : 2 * k], a.patches[:k])  # copy 1 is not
