"""Classifier benchmark: default training time and accuracy on unseen scenes, and
classify throughput (keyframes/s with m = 20 MC-dropout passes).

    .venv/bin/python benchmarks/bench_classify.py [--threads 2] [--features cfar|labels]
        [--train harbour:100:12,pier:101:6] [--test marina:0:20,pier:2:4] [--stride 4]

Trains on the pipeline's default training sets (`training.sets`) unless told otherwise
and tests on the default marina (the demo mission) and a pier seed never trained on.
Frames are every `stride`-th ping, rendered before timing; classify time covers DBSCAN,
patch cropping and the CNN (feature detection is the features stage's cost). Recall is
also reported per centroid-range band: a 1 deg beam is 0.35-0.5 m wide at 20-30 m, as
wide as a piling, so its shape is hardly resolved there.

Measured 2026-11-30 (defaults, CFAR features, 2 cores mostly idle):
- training: 2315 objects, 120 epochs, 188 s; validation accuracy 0.88.
- default marina (361 frames, 9.9 objects/frame), threshold 0.99: cylindrical precision
  0.980 (1080 accepted), recall 0.75; rectangular precision 0.925 (504), recall 0.65;
  piling recall 0.72 (argmax 0.88). By range: 0.89 / 0.91 / 0.87 / 0.81 at 0-8 / 8-12 /
  12-16 / 16-20 m, 0.62 at 20-25 m, 0.49 at 25-30 m (48 % of the marina's piling
  sightings are beyond 20 m).
- pier seed 2 (62 frames): cylindrical precision 1.00 (315 accepted), piling recall
  0.80; rectangular 4 of 7 accepted correct (6 in the scene).
- classify: 46 keyframes/s on the marina with the 2-thread figure of this script before
  the DBSCAN replacement; 54 keyframes/s on one thread (as the stage runs) after it.
- before the 2026-11-30 changes (16/32 filters, noise 0.05, +-20 deg; same sets, trained
  on all their objects): marina piling recall at 0.99 0.34, pier 0.32.
"""

from __future__ import annotations

import argparse
import itertools
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


def _sets(text: str) -> list[tuple[str, int, int]]:
    """ "scene:seed:goals,..." -> [(scene, seed, goals)]."""
    out = []
    for item in text.split(","):
        scene, seed, goals = item.split(":")
        out.append((scene, int(seed), int(goals)))
    return out


def by_range(objects: pa.Table, edges_m: tuple[float, ...]) -> list[dict[str, object]]:
    """Piling recall (accepted and correct / true pilings) per centroid-range band."""
    truth = np.asarray(objects["true_class_name"].to_pylist())
    pred = np.asarray(objects["class_name"].to_pylist())
    argmax = np.asarray(objects["argmax_class_name"].to_pylist())
    r = objects["range_m"].to_numpy()
    pil = np.isin(truth, PILING_CLASSES)
    rows = []
    for lo, hi in itertools.pairwise(edges_m):
        sel = pil & (r >= lo) & (r < hi)
        if sel.any():
            rows.append(
                {
                    "range_m": f"{lo:g}-{hi:g}",
                    "pilings": int(sel.sum()),
                    "recall": round(float((pred[sel] == truth[sel]).mean()), 3),
                    "argmax_recall": round(float((argmax[sel] == truth[sel]).mean()), 3),
                }
            )
    return rows


def main() -> None:
    from pipeline.training import TrainingDataConfig

    default_train = ",".join(f"{s.scene}:{s.seed}:{s.goals}" for s in TrainingDataConfig().sets)
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--features", choices=("cfar", "labels"), default="cfar")
    ap.add_argument(
        "--train", default=default_train, help="scene:seed:goals,... (default: the pipeline's)"
    )
    ap.add_argument("--test", default="marina:0:20,pier:2:4", help="scene:seed:goals,...")
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
        data = []
        for scene, seed, goals in _sets(args.train):
            frames = keyframes(scene, seed, goals, args.stride)
            data.append((frames, features(frames, args.features)))
        t0 = time.perf_counter()
        trained = train_classifier(data, tcfg)
        train_s = time.perf_counter() - t0
        if args.model_out:
            args.model_out.write_bytes(trained["model"])
        m = trained["metrics"]
        del data

    model, names, mcfg = model_from_bytes(trained["model"])
    ccfg = ClassifyConfig(overlay=False)
    report: dict[str, object] = {
        "threads": args.threads,
        "features": args.features,
        "train": {
            "sets": args.train,
            "samples": m["n_train"],
            "seconds": round(train_s, 1),
            "validation_accuracy": m["accuracy"],
            "validation_accepted_fraction": m["accepted_fraction"],
            "config": overrides,
        },
    }
    for scene, seed, goals in _sets(args.test):
        test_frames = keyframes(scene, seed, goals, args.stride)
        test_feats = features(test_frames, args.features)
        classify_keyframes(test_frames[:3], test_feats, model, names, mcfg, ccfg)  # warm-up
        t0 = time.perf_counter()
        objects, _, _ = classify_keyframes(test_frames, test_feats, model, names, mcfg, ccfg)
        classify_s = time.perf_counter() - t0
        report[f"{scene}:{seed}"] = {
            "keyframes": len(test_frames),
            "objects_per_keyframe": round(objects.num_rows / len(test_frames), 2),
            "mc_passes": ccfg.mc_passes,
            "classify_seconds": round(classify_s, 3),
            "keyframes_per_s": round(len(test_frames) / classify_s, 1),
            "scores": scores(objects),
            "by_range": by_range(objects, (0, 8, 12, 16, 20, 25, 30)),
        }
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
