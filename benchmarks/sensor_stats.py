"""Background statistics of real and simulated sonar images (issue 39, item 2; issue 50).

    .venv/bin/python -m benchmarks.sensor_stats [--frames 12] [--draws 24] [--presets]

Per image, `sonarmap.sim.randomise.image_statistics`: the background median (8-bit levels) and the
speckle contrast (std / mean of the pixels at or below the 80th percentile). Reported as
the median over images, for the real Oculus ping (`shared/data/oculus`, decoded by the
project's raw-Oculus reader), the real ARIS frames (`shared/data/aris`, the ARIS reader),
the simulator's default marina (horizontal sonar, `--frames` pings spread over a 4-goal
mission), and the marina under `--draws` sensor draws of the default
`SensorRandomisation` (the training missions' spread: min / median / max over draws).

Issue 50: each real file's whole image character (`sonarmap.sim.image_stats`: also the
background's lag-1 autocorrelation along range and beams and the median per range band),
the figures the presets' `image:` blocks state; `--presets` simulates every sensor
(`sonarmap simulate --sonar NAME`) on the marina and prints the same statistics.

Measured 2026-12-06: Oculus (1 ping) 43 / 0.642, lag-1 0.347 range / 0.636 beam, band
medians 8 .. 124 .. 56 (the seafloor's); ARIS (6 frames) 89 / 0.276, 0.373 / 0.225, -8.8 dB
from near to far (139 .. 58.5).

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


def _character(images: list[np.ndarray]) -> dict[str, object]:
    from sonarmap.sim.image_stats import image_character

    return image_character(images)


def preset_stats(frames: int, seed: int = 0) -> dict[str, dict[str, object]]:
    """Per simulated sensor (`sim-clean` and every preset with an image block): the
    image character of `frames` horizontal pings over a 2-goal marina mission."""
    from sonarmap.pipeline.training.datasets import read_scene, scene_path, sim_config
    from sonarmap.pipeline.training.sim_sensors import sensor_names, with_sensors
    from sonarmap.sim.dataset import simulate

    scene, out = read_scene(scene_path("marina")), {}
    for name in sensor_names():
        cfg = with_sensors(sim_config(2, 30.0), {"horizontal": name, "vertical": name})
        run = simulate(scene, cfg, seed)
        idx = np.linspace(0, run.n_frames - 1, frames).round().astype(int)
        out[name] = _character([run.frame(int(i)).horizontal.image for i in idx])
    return out


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
    ap.add_argument("--presets", action="store_true", help="also simulate every sensor preset")
    args = ap.parse_args()
    from sonarmap.sim.randomise import SensorRandomisation, draw_sensor

    doc: dict[str, object] = {
        "oculus": _character(oculus_images(SHARED / "oculus" / "one_ping_8bit.raw")),
        "aris": _character(aris_images(SHARED / "aris" / "sample.aris")),
        "sim_marina": _median_stats(sim_images(args.frames)),
    }
    if args.presets:
        doc["sim_presets"] = preset_stats(max(args.frames // 2, 2))
    per_draw = []
    for k in range(args.draws):
        draw = draw_sensor(SensorRandomisation(), 5000 + k)
        s = _median_stats(sim_images(max(args.frames // 4, 2), draw, seed=k))
        per_draw.append((s["background_median"], s["speckle_contrast"]))
    arr = np.array(per_draw).reshape(-1, 2)
    doc["sim_randomised"] = (
        {}
        if not per_draw
        else {
            "draws": args.draws,
            "background_median": [float(v) for v in np.percentile(arr[:, 0], [0, 50, 100])],
            "speckle_contrast": [
                round(float(v), 3) for v in np.percentile(arr[:, 1], [0, 50, 100])
            ],
        }
    )
    print(json.dumps(doc, indent=2))


if __name__ == "__main__":
    main()
