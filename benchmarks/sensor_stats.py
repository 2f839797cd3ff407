"""Background statistics of real and simulated sonar images (issue 39, item 2).

    .venv/bin/python benchmarks/sensor_stats.py [--frames 12] [--draws 24]

Per image, `sonarmap.sim.randomise.image_statistics`: the background median (8-bit levels) and the
speckle contrast (std / mean of the pixels at or below the 80th percentile). Reported as
the median over images, for the real Oculus ping (`shared/data/oculus`, decoded by the
project's raw-Oculus reader), the real ARIS frames (`shared/data/aris`, the ARIS reader),
the simulator's default marina (horizontal sonar, `--frames` pings spread over a 4-goal
mission), and the marina under `--draws` sensor draws of the default
`SensorRandomisation` (the training missions' spread: min / median / max over draws).

Measured 2026-12-03 (`--frames 12 --draws 24`): Oculus 43 / 0.642 (one ping), ARIS 89 /
0.276 (6 frames), simulated marina 4 / 0.453; the 24 randomised draws span medians 2-120
(median 12) and contrasts 0.226-0.682 (median 0.321), so both real sensors lie inside.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"


def _median_stats(images: list[np.ndarray]) -> dict[str, float]:
    from sonarmap.sim.randomise import image_statistics

    stats = np.array([image_statistics(im) for im in images])
    return {
        "images": len(images),
        "background_median": round(float(np.median(stats[:, 0])), 2),
        "speckle_contrast": round(float(np.median(stats[:, 1])), 3),
    }


def oculus_images(path: Path) -> list[np.ndarray]:
    from sonarmap.pipeline.readers.oculus_raw import parse_ping

    buf, pos, out = path.read_bytes(), 0, []
    while pos < len(buf):
        ping, pos = parse_ping(buf, pos)
        out.append(np.asarray(ping.image))
    return out


def aris_images(path: Path) -> list[np.ndarray]:
    from sonarmap.pipeline.readers.aris import ArisSource

    src = ArisSource(path)
    return [src.frame(int(k)).image for k in src._order]


def sim_images(frames: int, draw: dict | None = None, seed: int = 0) -> list[np.ndarray]:
    from sonarmap.pipeline.training.datasets import read_scene, scene_path, sim_config
    from sonarmap.sim.dataset import simulate
    from sonarmap.sim.randomise import randomised_config

    cfg = sim_config(4, None)
    if draw is not None:
        cfg = randomised_config(cfg, draw)
    run = simulate(read_scene(scene_path("marina")), cfg, seed)
    idx = np.linspace(0, run.n_frames - 1, frames).round().astype(int)
    return [run.frame(int(i)).horizontal.image for i in idx]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--draws", type=int, default=24)
    args = ap.parse_args()
    from sonarmap.sim.randomise import SensorRandomisation, draw_sensor

    doc: dict[str, object] = {
        "oculus": _median_stats(oculus_images(SHARED / "oculus" / "one_ping_8bit.raw")),
        "aris": _median_stats(aris_images(SHARED / "aris" / "sample.aris")),
        "sim_marina": _median_stats(sim_images(args.frames)),
    }
    per_draw = []
    for k in range(args.draws):
        draw = draw_sensor(SensorRandomisation(), 5000 + k)
        s = _median_stats(sim_images(max(args.frames // 4, 2), draw, seed=k))
        per_draw.append((s["background_median"], s["speckle_contrast"]))
    arr = np.array(per_draw)
    doc["sim_randomised"] = {
        "draws": args.draws,
        "background_median": [float(v) for v in np.percentile(arr[:, 0], [0, 50, 100])],
        "speckle_contrast": [round(float(v), 3) for v in np.percentile(arr[:, 1], [0, 50, 100])],
    }
    print(json.dumps(doc, indent=2))


if __name__ == "__main__":
    main()
