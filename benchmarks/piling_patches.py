"""Piling patches as the classifier sees them, clean sensor against a noisy one (issue 50).

    .venv/bin/python -m benchmarks.piling_patches OUT.png CLEAN_STORE NOISY_STORE

Each store holds one `sonarmap run` of a simulated recording (same scene and mission).
The patches are cut by the shipped code (`sonarmap.stages.classify.objects.extract_objects`,
the shipped model's clustering and crop settings, background normalisation) from every
7th keyframe, six true cylindrical and six true rectangular pilings per row pair. The
last row pair cuts the noisy run's patches again with `train.patch_normalisation: grain`
(each range's 90th percentile as its background level instead of its median).
`docs/img/piling_patches_sensors.png` is marina seed 0, 6 goals, clean against the
Oculus pair (`benchmarks.bench_sensors`' recordings).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from sonarmap.pipeline.formats.frames_io import read_frames
from sonarmap.schemas.classes import DEFAULT_TABLE
from sonarmap.stages.classify import objects as O

CLASSES = ("cylindrical_piling", "rectangular_piling")
PER_ROW = 6


def patches(store: Path, normalisation: str) -> dict[str, list[np.ndarray]]:
    """Up to PER_ROW patches per piling class from every 7th keyframe of the store's run."""
    (frames_path,) = store.glob("keyframes/*/keyframes.mcap")
    (features_path,) = store.glob("features/*/features.parquet")
    by_kf = O.horizontal_features(pq.read_table(features_path))
    got: dict[str, list[np.ndarray]] = {c: [] for c in CLASSES}
    for frame in read_frames(frames_path):
        f = by_kf.get(frame.keyframe_id)
        if frame.keyframe_id % 7 or f is None:
            continue
        objs = O.extract_objects(
            frame.horizontal, f["range_bin"], f["beam"], f["range_m"], f["angle_rad"],
            eps_m=0.25, min_samples=2, min_features=10, margin_m=0.2, min_side_m=1.0,
            normalisation=normalisation,
        )  # fmt: skip
        for patch, c in zip(objs.patches, objs.true_class_id, strict=True):
            name = DEFAULT_TABLE.name_of(int(c))
            if name in got and len(got[name]) < PER_ROW:
                got[name].append(patch)
    return got


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("clean", type=Path)
    ap.add_argument("noisy", type=Path)
    args = ap.parse_args()
    blocks = [
        ("clean sensor", patches(args.clean, "background")),
        ("noisy sensor (shipped normalisation)", patches(args.noisy, "background")),
        ("noisy sensor, normalisation 'grain'", patches(args.noisy, "grain")),
    ]
    fig, ax = plt.subplots(
        6, PER_ROW, figsize=(6, 6.9), gridspec_kw={"hspace": 0.08, "wspace": 0.04}
    )
    for i, (title, got) in enumerate(blocks):
        for j, cls in enumerate(CLASSES):
            for k in range(PER_ROW):
                a = ax[2 * i + j, k]
                a.set_xticks([])
                a.set_yticks([])
                if k < len(got[cls]):
                    a.imshow(got[cls][k], cmap="gray", vmin=0, vmax=1)
            ax[2 * i + j, 0].set_ylabel(cls.split("_")[0][:4] + ".", fontsize=7)
        ax[2 * i, 0].set_title(title, fontsize=8, loc="left", pad=2)
    fig.subplots_adjust(left=0.05, right=0.99, top=0.96, bottom=0.01)
    fig.savefig(args.out, dpi=70)


if __name__ == "__main__":
    main()
