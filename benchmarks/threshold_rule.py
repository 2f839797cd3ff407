"""The acceptance-threshold rule on a model's own validation split (issue 50).

    .venv/bin/python -m benchmarks.threshold_rule MODEL_DIR TRAINING_STORE [--min-precision 0.97]

MODEL_DIR is a `train` artifact (`sonarmap train -o DIR`); TRAINING_STORE the store its
datasets' keyframes and features artifacts are in (`<training.directory>/store`). The
validation keyframe blocks of every dataset (`train.split: keyframes`, noisy copies
included, as the train stage validates) are cut again and scored with the model's MC
dropout (single view). Prints, per threshold, the precision and recall of the accepted
piling calls, overall and per dataset, and the rule's choice: the lowest threshold whose
piling precision is at least `--min-precision`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from sonarmap.pipeline.formats.frames_io import read_frames
from sonarmap.schemas.classes import DEFAULT_TABLE, PILING_CLASSES
from sonarmap.stages.classify import cnn
from sonarmap.stages.classify.train import TrainConfig, collect_samples

THRESHOLDS = (0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.93, 0.95, 0.97, 0.98, 0.99)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", type=Path)
    ap.add_argument("store", type=Path)
    ap.add_argument("--min-precision", type=float, default=0.97)
    args = ap.parse_args()
    manifest = json.loads((args.model / "manifest.json").read_text())
    cfg = TrainConfig(**manifest["recipe"]["config"])
    inputs = manifest["input_artifacts"]
    n_sets = sum(k.startswith("keyframes_") for k in inputs)

    def validates(keyframe_id: int) -> bool:  # as `split_train_val`
        block = keyframe_id // cfg.val_block_keyframes
        return block % cfg.val_every_blocks == cfg.val_every_blocks - 1

    datasets = []
    for i in range(n_sets):
        frames = read_frames(args.store / inputs[f"keyframes_{i}.frames"] / "keyframes.mcap")
        features = pq.read_table(args.store / inputs[f"features_{i}.features"] / "features.parquet")
        datasets.append(([f for f in frames if validates(f.keyframe_id)], features))
    samples = collect_samples(datasets, cfg)
    model, names, _ = cnn.model_from_bytes((args.model / "model.pt").read_bytes())
    ids = [DEFAULT_TABLE.ids[n] for n in names]
    keep = np.isin(samples.class_id, ids)
    target = np.searchsorted(np.sort(ids), samples.class_id[keep])
    target = np.argsort(ids)[target]  # label id -> the model's output index
    dataset = samples.dataset[keep]
    mean, _ = cnn.mc_predict(model, samples.patches[keep], cfg.mc_passes, cfg.seed)
    pred, p = mean.argmax(axis=1), mean.max(axis=1)
    is_piling = np.isin(np.asarray(names), PILING_CLASSES)
    pile, called = is_piling[target], is_piling[pred]
    print(f"validation objects {len(target)}, pilings {pile.sum()}, per dataset"
          f" {np.bincount(dataset).tolist()}")  # fmt: skip
    chosen = None
    for t in THRESHOLDS:
        acc = called & (p > t)
        right = acc & (pred == target)
        precision = right.sum() / max(acc.sum(), 1)
        cells = [f"t={t}: precision {precision:.3f} recall {right.sum() / pile.sum():.3f}"]
        for d in range(n_sets):
            m = dataset == d
            cells.append(
                f"set {d} {(right & m).sum() / max((acc & m).sum(), 1):.2f}"
                f"/{(right & m).sum() / max((pile & m).sum(), 1):.2f}"
            )
        print("  ".join(cells))
        if chosen is None and acc.any() and precision >= args.min_precision:
            chosen = t
    print(f"rule: lowest threshold with piling precision >= {args.min_precision}: {chosen}")


if __name__ == "__main__":
    main()
