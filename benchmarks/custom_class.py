"""A class defined only in config, end to end (issue 38's target): `mooring_block`.

    PYTHONPATH=. .venv/bin/python benchmarks/custom_class.py [--work /tmp/sonarmap-custom-class]
        [--train-seed 11] [--test-seed 12] [--goals 8] [--test-goals 5]

1. The class table is extended in a config file (`classes.add`: mooring_block, id 7, an
   object-frame class, inferred) that also lists the labelled recording under
   `training.recorded`; the default training sets stay.
2. The scene `configs/scenes/mooring_field.yaml` (eight blocks from the mesh
   `configs/scenes/meshes/mooring_block.obj`, written by `mooring_block_obj` below, among
   pilings, a seawall and a boat) is simulated with that table twice: a training mission
   and a test mission with another seed.
3. Labelling as a user would, with a script standing in for the person at CVAT or Label
   Studio: `sonarmap label export` writes fan images and a COCO file, `label_coco` fills it
   with polygons of the simulator's truth (the outline of every labelled class's returns, in
   pixels, as a labeller draws them), `sonarmap label import` turns it into
   `train.annotations.yaml`. Export and import are timed on 3 keyframes, then run on every
   keyframe of the training mission.
4. `sonarmap run` on the test mission with the config trains the classifier (default sets +
   the recording, table extended) and maps; objects and maps are scored against the
   simulator's truth: mooring_block object precision and recall (classify's objects, their
   label-image class), and the inferred points' median error against the fused points'
   (evaluate's per-class figures).

Targets: precision >= 0.9, recall >= 0.7, inferred median <= 1.5x fused median. The script
prints every figure and exits 1 when a target is missed.

Measured 2026-12-03 (defaults: train seed 11 with 8 goals, test seed 12 with 5 goals; 2
cores shared with other jobs, load 6-13), `--work /tmp/classes-work/bench`:
- labelling 3 keyframes: one export command 14.6 s the first time (it runs the keyframes
  stage), 4.1 s with it cached; one import command 3.5 s (88 shapes). All 70 keyframes:
  export 29.2 s, import 7.5 s (2227 shapes).
- training (default sets + the recording) and the test run: 2376 s wall on the loaded box.
- mooring_block on the test mission: precision 1.000, recall 0.986 (142 sightings);
  inferred median error 0.103 m vs its fused points' 0.103 m (0.99x); semantic map 4360
  accurate voxels vs the standard map's 1384, completeness 0.51 vs 0.22. Other classes:
  cylindrical 1.00 / 1.00, rectangular 0.96 / 0.80, seawall 1.00 / 0.84, hull 1.00 / 0.86
  (precision / recall).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "configs" / "scenes" / "mooring_field.yaml"
MESH = ROOT / "configs" / "scenes" / "meshes" / "mooring_block.obj"
CLASS = "mooring_block"
CONFIG = """\
classes:
  add:
    - {{name: {cls}, id: 7, frame_kind: object, inferred: true, colour: '#8c564b'}}
training:
  recorded: [{recording}]
"""
LINK_M = 0.6
"""Returns of one class closer than this belong to one drawn outline."""
SEAFLOOR_TILE_M = 6.0
"""The seafloor's returns are outlined tile by tile (its arc's hull would cover objects)."""
PAD_M = 0.1
"""Outlines are drawn this far outside the returns (a labeller's margin)."""


def mooring_block_obj(a: float = 0.8, b: float = 0.6, h: float = 2.0, c: float = 0.25) -> str:
    """OBJ text of a concrete block 2a x 2b x h [m] with its top edges chamfered by c."""
    v = []
    for z, inset in ((0.0, 0.0), (h - c, 0.0), (h, c)):
        v += [(-a + inset, -b + inset, z), (a - inset, -b + inset, z),
              (a - inset, b - inset, z), (-a + inset, b - inset, z)]  # fmt: skip
    f = [(1, 3, 2), (1, 4, 3), (9, 10, 11), (9, 11, 12)]
    for ring in (0, 4):
        for k in range(4):
            p, q = ring + k + 1, ring + (k + 1) % 4 + 1
            f += [(p, q, q + 4), (p, q + 4, p + 4)]
    lines = ["# mooring block: 1.6 m x 1.2 m, 2.0 m tall, top edges chamfered 0.25 m"]
    lines += [f"v {x:g} {y:g} {z:g}" for x, y, z in v] + [f"f {i} {j} {k}" for i, j, k in f]
    return "\n".join(lines) + "\n"


def sonarmap(*args: str, cache: Path) -> tuple[float, str]:
    """Run the CLI; (seconds, stdout). Exits on failure with its output."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "SONARMAP_CACHE_DIR": str(cache)}
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "sonarmap.pipeline", *args], env=env, capture_output=True, text=True
    )
    if done.returncode != 0:
        sys.exit(f"sonarmap {' '.join(args)} failed:\n{done.stdout}\n{done.stderr}")
    return time.perf_counter() - t0, done.stdout


def _outlines(xy: np.ndarray, tile_m: float | None) -> list[np.ndarray]:
    """Padded convex outlines (k, 2) [m] of the groups of points `xy` (n, 2) [m]."""
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import ConvexHull, QhullError, cKDTree

    if tile_m is not None:
        _, group = np.unique(np.floor(xy / tile_m).astype(np.int64), axis=0, return_inverse=True)
    else:
        pairs = cKDTree(xy).sparse_distance_matrix(cKDTree(xy), LINK_M, output_type="coo_matrix")
        group = connected_components(pairs, directed=False)[1]
    out = []
    for g in np.unique(group):
        pts = xy[group.ravel() == g]
        # Each point as a small square: the hull then has area even for one return.
        corners = (pts[:, None, :] + PAD_M * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]])).reshape(-1, 2)  # fmt: skip
        try:
            out.append(corners[ConvexHull(corners).vertices])
        except QhullError:
            continue
    return out


def label_coco(coco_path: Path, table: Any, scene: Path, seed: int, goals: int) -> int:
    """Fill an exported COCO file with the simulator's truth, as a labeller would; returns
    the number of shapes written. The label images come from simulating the mission again
    (same scene, seed and goals: same frames)."""
    from sonarmap.pipeline.labels.fan_image import FanGeometry, metres_to_pixels
    from sonarmap.pipeline.training.datasets import read_scene, sim_config
    from sonarmap.sim.dataset import simulate
    from sonarmap.stages.kernels.geometry import fan_to_xy

    doc = json.loads(coco_path.read_text())
    geometry = json.loads((coco_path.parent / "geometry.json").read_text())["images"]
    config = sim_config(goals, None)
    run = simulate(read_scene(scene), config, seed, table)
    dt_ns = round(1e9 / config.ping_rate_hz)
    category = {c["name"]: c["id"] for c in doc["categories"]}
    annotations = []
    for image in doc["images"]:
        entry = geometry[image["file_name"]]
        g = FanGeometry(**{k: entry[k] for k in ("width_px", "height_px", "pixel_m", "x_top_m", "y_left_m")})  # fmt: skip
        ping = run.frame(round((entry["t_ns"] - config.start_time_ns) / dt_ns)).horizontal
        assert ping.t_ns == entry["t_ns"] and ping.labels is not None
        r, b = np.nonzero(ping.labels)
        xy = fan_to_xy(ping.ranges_m[r], ping.angles_rad[b]).reshape(-1, 2)
        cls = ping.labels[r, b]
        # The seafloor first: where outlines overlap, the later (an object's) wins.
        order = sorted(np.unique(cls).tolist(), key=lambda c: (table.name_of(c) != "seafloor", c))
        for c in order:
            name = table.name_of(int(c))
            tile = SEAFLOOR_TILE_M if name == "seafloor" else None
            for outline in _outlines(xy[cls == c], tile):
                flat = metres_to_pixels(outline, g).ravel().round(2).tolist()
                u, v = flat[0::2], flat[1::2]
                annotations.append({
                    "id": len(annotations) + 1, "image_id": image["id"],
                    "category_id": category[name], "segmentation": [flat],
                    "bbox": [min(u), min(v), max(u) - min(u), max(v) - min(v)],
                    "area": 0.0, "iscrowd": 0,
                })  # fmt: skip
    coco_path.write_text(json.dumps({**doc, "annotations": annotations}))
    return len(annotations)


def _keyframe_ids(coco_path: Path) -> list[int]:
    geometry = json.loads((coco_path.parent / "geometry.json").read_text())["images"]
    return sorted(e["keyframe_id"] for e in geometry.values())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("/tmp/sonarmap-custom-class"))
    parser.add_argument("--train-seed", type=int, default=11)
    parser.add_argument("--test-seed", type=int, default=12)
    parser.add_argument("--goals", type=int, default=8)
    parser.add_argument("--test-goals", type=int, default=5)
    parser.add_argument(
        "--cache", type=Path, default=os.environ.get("SONARMAP_CACHE_DIR"),
        help="SONARMAP_CACHE_DIR of the commands (default: $SONARMAP_CACHE_DIR, else WORK/cache)",
    )  # fmt: skip
    args = parser.parse_args()
    if MESH.read_text() != mooring_block_obj():
        sys.exit(f"{MESH} differs from mooring_block_obj(): regenerate it")
    work, cache = args.work, args.cache or args.work / "cache"
    work.mkdir(parents=True, exist_ok=True)
    store = work / "store"
    train, test = work / "train.mcap", work / "test.mcap"
    config = work / "config.yaml"
    config.write_text(CONFIG.format(cls=CLASS, recording=train))
    from sonarmap.pipeline.engine.config.load import load_config
    from sonarmap.pipeline.graph import all_stages, extra_sections

    table = load_config(all_stages(), config, (), extra_sections()).classes  # type: ignore[attr-defined]

    for path, seed, goals in ((train, args.train_seed, args.goals), (test, args.test_seed, args.test_goals)):  # fmt: skip
        if not path.exists():
            s, _ = sonarmap("simulate", "--scene", str(SCENE), "--config", str(config),
                            "--seed", str(seed), "--goals", str(goals), "-o", str(path), "-q", cache=cache)  # fmt: skip
            print(f"simulated {path.name} (seed {seed}, {goals} goals) in {s:.0f} s")

    # One export and one import command for 3 keyframes, timed (the labeller in between).
    ann = train.with_suffix("").with_suffix(".annotations.yaml")
    ann.unlink(missing_ok=True)
    common = ("--config", str(config), "--store", str(store))
    three = work / "labels3"
    t_export, _ = sonarmap("label", "export", str(train), "-o", str(three), "--keyframes", "4,12,20", *common, cache=cache)  # fmt: skip
    coco3 = three / f"{train.stem}.coco.json"
    n3 = label_coco(coco3, table, SCENE, args.train_seed, args.goals)
    t_import, _ = sonarmap("label", "import", str(coco3), "-o", str(work / "three.annotations.yaml"), "--force", "--config", str(config), cache=cache)  # fmt: skip
    print(f"3 keyframes: export {t_export:.1f} s, import {t_import:.1f} s ({n3} shapes)")

    # Every keyframe of the training mission, the same way.
    every = work / "labels"
    t_all, _ = sonarmap("label", "export", str(train), "-o", str(every), *common, cache=cache)
    coco = every / f"{train.stem}.coco.json"
    label_coco(coco, table, SCENE, args.train_seed, args.goals)
    t_imp, out = sonarmap("label", "import", str(coco), "--force", "--config", str(config), cache=cache)  # fmt: skip
    print(f"all {len(_keyframe_ids(coco))} keyframes: export {t_all:.1f} s, import {t_imp:.1f} s: {out.strip()}")  # fmt: skip

    # Train (default sets + the recording) and map the test mission.
    t_run, out = sonarmap("run", str(test), *common, "--json", cache=cache)
    print(f"run (training included on first use): {t_run:.0f} s")
    _report(store, test, config, cache)


def _report(store: Path, test: Path, config: Path, cache: Path) -> None:
    os.environ["SONARMAP_CACHE_DIR"] = str(cache)
    from sonarmap.pipeline.api import RunRequest, run_dataset
    from sonarmap.pipeline.engine.store.codecs import read_verified
    from sonarmap.pipeline.graph import stage_by_name
    from sonarmap.pipeline.scoring import classification_scores

    result, _ = run_dataset(RunRequest(test, config_path=config, store_dir=store))
    objects_out = next(o for o in stage_by_name("classify").outputs if o.name == "objects")
    objects = read_verified(result.artifacts["classify"], objects_out)
    scores = classification_scores(objects)["per_class"]
    metrics = json.loads((result.artifacts["evaluate"].path / "metrics.json").read_text())
    per_class = metrics["per_class"]["classes"].get(CLASS, {})
    fused = (per_class.get("standard") or {}).get("median_error_m")
    inferred = (per_class.get("inferred") or {}).get("median_error_m")
    mb = scores.get(CLASS, {})
    print(json.dumps({"classify": scores, CLASS: per_class}, indent=1, default=str))
    precision, recall = mb.get("precision") or 0.0, mb.get("recall") or 0.0
    ratio = inferred / fused if inferred is not None and fused else float("inf")
    print(
        f"{CLASS}: precision {precision:.3f} (target >= 0.9), recall {recall:.3f} (>= 0.7),"
        f" support {mb.get('support')}; median error inferred {inferred} m vs fused {fused} m"
        f" = {ratio:.2f}x (<= 1.5x)"
    )
    if not (precision >= 0.9 and recall >= 0.7 and ratio <= 1.5):
        sys.exit(1)


if __name__ == "__main__":
    main()
