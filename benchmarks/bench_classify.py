"""Classifier benchmark: default training time and accuracy on an unseen scene, and
classify throughput (keyframes/s with m = 20 MC-dropout passes).

    .venv/bin/python benchmarks/bench_classify.py [--threads 2] [--features cfar|labels]
        [--train-scene marina --train-seed 1 --test-scene pier --test-seed 2] [--stride 4]

Frames are rendered before timing; classify time covers DBSCAN, patch cropping and
the CNN (feature detection is the features stage's cost, not counted here).

Measured 2026-11-23 (`--threads 2 --features cfar`, train marina seed 1 / test pier
seed 2, stride 4; 1272 training objects, 62 test keyframes, 6.8 objects/keyframe):
- classify: 112 keyframes/s on 2 threads (idle machine), 98 on 1 thread, m = 20.
- training: 47 s for 60 epochs (idle machine); 120 epochs (the default) 245 s with
  the machine shared (load ~3).
- unseen pier, 120 epochs, threshold 0.99: cylindrical_piling precision 1.00
  (195 accepted), piling recall 0.49; argmax recall 0.93; at threshold 0.8: precision
  1.00, recall 0.83. rectangular_piling: 6 objects in the pier, none accepted at 0.99.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import torch

from schemas.classes import PILING_CLASSES, UNKNOWN_CLASS
from schemas.sonar import KeyframeImages
from stages.classify import ClassifyConfig, classify_keyframes
from stages.cnn import model_from_bytes
from stages.train import TrainConfig, features_from_labels, train_classifier

ROOT = Path(__file__).resolve().parents[1]


def keyframes(scene: str, seed: int, goals: int, stride: int) -> list[KeyframeImages]:
    from sim.config import MissionConfig, SimConfig
    from sim.dataset import simulate
    from sim.scene import load_scene

    cfg = SimConfig(mission=MissionConfig(n_goals=goals))
    run = simulate(load_scene(ROOT / f"configs/scenes/{scene}.yaml"), cfg, seed)
    frames = [run.frame(i) for i in range(0, run.n_frames, stride)]
    return [KeyframeImages(k, f.t_ns, f.horizontal, f.vertical) for k, f in enumerate(frames)]


def features(frames: list[KeyframeImages], kind: str) -> pa.Table:
    if kind == "cfar":
        from stages.features import FeaturesConfig, features_table

        return features_table(frames, FeaturesConfig())
    parts = []
    for fr in frames:
        f = features_from_labels(fr)
        n = len(f["feature_id"])
        cols = {k: v for k, v in f.items() if k != "feature_id"}
        parts.append(
            pa.table(
                {
                    "keyframe_id": np.full(n, fr.keyframe_id, np.int64),
                    "feature_id": f["feature_id"] + 1_000_000 * fr.keyframe_id,
                    "sonar": pa.array(["horizontal"] * n, pa.string()),
                    **cols,
                }
            )
        )
    return pa.concat_tables(parts)


def scores(objects: pa.Table) -> dict[str, object]:
    pred = np.asarray(objects["class_name"].to_pylist())
    truth = np.asarray(objects["true_class_name"].to_pylist())
    argmax = np.asarray(objects["argmax_class_name"].to_pylist())
    out: dict[str, object] = {"objects": len(pred), "accepted": int((pred != UNKNOWN_CLASS).sum())}
    for name in PILING_CLASSES:
        acc = pred == name
        out[name] = {
            "support": int((truth == name).sum()),
            "accepted": int(acc.sum()),
            "accepted_precision": float((truth[acc] == name).mean()) if acc.any() else None,
            "recall": float((pred[truth == name] == name).mean())
            if (truth == name).any()
            else None,
            "argmax_recall": float((argmax[truth == name] == name).mean())
            if (truth == name).any()
            else None,
        }
    pil = np.isin(truth, PILING_CLASSES)
    out["piling_recall"] = float((pred[pil] == truth[pil]).mean()) if pil.any() else None
    prob = objects["probability"].to_numpy()
    curve = {}
    for t in (0.5, 0.8, 0.9, 0.95, 0.98, 0.99):
        acc = prob > t
        row: dict[str, object] = {}
        for name in PILING_CLASSES:
            sel = acc & (argmax == name)
            row[f"{name}_precision"] = float((truth[sel] == name).mean()) if sel.any() else None
            row[f"{name}_accepted"] = int(sel.sum())
        row["piling_recall"] = float((acc & (argmax == truth))[pil].mean()) if pil.any() else None
        curve[str(t)] = row
    out["threshold_curve"] = curve
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--features", choices=("cfar", "labels"), default="labels")
    ap.add_argument("--train-scene", default="marina")
    ap.add_argument("--train-seed", type=int, default=1)
    ap.add_argument("--train-goals", type=int, default=6)
    ap.add_argument("--test-scene", default="pier")
    ap.add_argument("--test-seed", type=int, default=2)
    ap.add_argument("--test-goals", type=int, default=4)
    ap.add_argument("--stride", type=int, default=4)
    ap.add_argument("--set", action="append", default=[], help="TrainConfig field=json")
    ap.add_argument("--model-out", type=Path, default=None)
    ap.add_argument("--model-in", type=Path, default=None, help="skip training, use this model")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    overrides = {k: json.loads(v) for k, v in (s.split("=", 1) for s in args.set)}
    tcfg = TrainConfig(**overrides)

    if args.model_in:
        trained = {"model": args.model_in.read_bytes()}
        m: dict = {"n_train": None, "accuracy": None, "accepted_fraction": None}
        train_s = float("nan")
    else:
        train_frames = keyframes(args.train_scene, args.train_seed, args.train_goals, args.stride)
        train_feats = features(train_frames, args.features)
        t0 = time.perf_counter()
        trained = train_classifier([(train_frames, train_feats)], tcfg)
        train_s = time.perf_counter() - t0
        if args.model_out:
            args.model_out.write_bytes(trained["model"])
        m = trained["metrics"]
        del train_frames

    test_frames = keyframes(args.test_scene, args.test_seed, args.test_goals, args.stride)
    test_feats = features(test_frames, args.features)
    model, names, mcfg = model_from_bytes(trained["model"])
    ccfg = ClassifyConfig(overlay=False)
    classify_keyframes(test_frames[:3], test_feats, model, names, mcfg, ccfg)  # warm-up
    t0 = time.perf_counter()
    objects, _, _ = classify_keyframes(test_frames, test_feats, model, names, mcfg, ccfg)
    classify_s = time.perf_counter() - t0
    report = {
        "threads": args.threads,
        "features": args.features,
        "train": {
            "scene": args.train_scene,
            "seed": args.train_seed,
            "samples": m["n_train"],
            "seconds": round(train_s, 1),
            "validation_accuracy": m["accuracy"],
            "validation_accepted_fraction": m["accepted_fraction"],
            "config": overrides,
        },
        "classify": {
            "scene": args.test_scene,
            "seed": args.test_seed,
            "keyframes": len(test_frames),
            "objects_per_keyframe": round(objects.num_rows / len(test_frames), 2),
            "mc_passes": ccfg.mc_passes,
            "seconds": round(classify_s, 3),
            "keyframes_per_s": round(len(test_frames) / classify_s, 1),
        },
        "unseen_scene": scores(objects),
    }
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
