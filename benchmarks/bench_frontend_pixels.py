"""Pixel-level yardstick of the detection front end (issue 50): on simulated pings, the
share of labelled pixels detected and the false-alarm rate on unlabelled pixels, per
sensor statistics and front-end variant. Not the headline map figure.

    .venv/bin/python benchmarks/bench_frontend_pixels.py [--scene marina] [--seed 0]
        [--pings 24] [--goals 4] [--sensors clean,oculus_like,aris_like,oculus_pair,aris_pair]

Variants: `old` (intensity floor 20, exponential-model tau, no filter: the front end
before issue 50), `calibrated_raw` (calibrated on the sampled pings, no filter) and
`calibrated` (the default, denoise auto), `calibrated_box3x3` (the 3x3 mean always),
`beam3` / `range3` (a 3-cell mean across beams / along range). `--fit` sets
`features.fit_quantiles`.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

SENSORS = {
    "clean": {},
    "oculus_like": {"noise_mean_level": 53.0, "noise_shape": 1.2},
    "aris_like": {"noise_mean_level": 88.0, "noise_shape": 3.4},
}
PRESET_PAIRS = {
    "oculus_pair": {"horizontal": "oculus-m750d-750khz", "vertical": "oculus-m1200d"},
    "aris_pair": {"horizontal": "aris1800-48", "vertical": "aris1800-48"},
}
"""The measured presets (grain along range and beam, range slope, gain): `--sensors`."""


def _pings(scene: str, seed: int, goals: int, n: int, sensor: str) -> list:
    from sonarmap.pipeline.training.datasets import read_scene, scene_path, sim_config
    from sonarmap.pipeline.training.sim_sensors import with_sensors
    from sonarmap.sim.dataset import simulate

    cfg = sim_config(goals, None)
    update = SENSORS.get(sensor, {})
    if sensor in PRESET_PAIRS:
        cfg = with_sensors(cfg, PRESET_PAIRS[sensor])
    elif update:
        cfg = cfg.model_copy(
            update={
                s: getattr(cfg, s).model_copy(update=update) for s in ("horizontal", "vertical")
            }
        )
    run = simulate(read_scene(scene_path(scene)), cfg, seed)
    idx = np.linspace(0, run.n_frames - 1, n).round().astype(int)
    return [run.frame(int(i)) for i in idx]


FIT = (0.6, 0.95)
VARIANTS = {
    "old": {"intensity_floor": 20.0, "threshold_factor": "exponential", "denoise": "none"},
    "calibrated_raw": {"denoise": "none"},
    "calibrated": {},
    "calibrated_box3x3": {"denoise": "box3x3"},
    "box3x5": {"denoise": "box3x5"},
    "box5x5": {"denoise": "box5x5"},
    "beam3": {"denoise": "beam3"},
    "range3": {"denoise": "range3"},
}
SEAFLOOR = 6


def measure(frames: list, variant: str) -> dict:
    from scipy.ndimage import binary_dilation

    from sonarmap.schemas.sonar import KeyframeImages
    from sonarmap.stages.features.calibration import calibrate
    from sonarmap.stages.features.config import FeaturesConfig
    from sonarmap.stages.kernels.frame_features import detect_mask
    from sonarmap.stages.kernels.front_end import thresholds

    cfg = FeaturesConfig(fit_quantiles=FIT, **VARIANTS[variant])
    frames = [KeyframeImages(i, f.t_ns, f.horizontal, f.vertical) for i, f in enumerate(frames)]
    th = thresholds(calibrate(frames, cfg))
    out = {}
    for sonar in ("horizontal", "vertical"):
        hit = lab = fa = bg = det = obj = obj_hit = 0
        for f in frames:
            ping = getattr(f, sonar)
            mask = detect_mask(ping, cfg, th[sonar])
            labelled = ping.labels > 0
            # Background: 2+ cells from any labelled pixel (a smoothed object's halo and
            # the simulator's blur are not false alarms of the detector).
            away = ~binary_dilation(labelled, np.ones((5, 5), bool))
            objects = labelled & (ping.labels != SEAFLOOR)
            obj += int(objects.sum())
            obj_hit += int((mask & objects).sum())
            hit += int((mask & labelled).sum())
            lab += int(labelled.sum())
            fa += int((mask & away).sum())
            bg += int(away.sum())
            det += int(mask.sum())
        out[sonar] = {
            "labelled_detected": round(hit / max(lab, 1), 4),
            "object_detected": round(obj_hit / max(obj, 1), 4),
            "false_alarm_rate": float(f"{fa / max(bg, 1):.3g}"),
            "detections_per_ping": round(det / len(frames), 1),
            "false_alarms_per_ping": round(fa / len(frames), 1),
        }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="marina")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pings", type=int, default=24)
    ap.add_argument("--goals", type=int, default=4)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--fit", default="0.6,0.95")
    ap.add_argument("--sensors", default=",".join(SENSORS))
    args = ap.parse_args()
    global FIT
    FIT = tuple(float(x) for x in args.fit.split(","))
    doc = {}
    for name in args.sensors.split(","):
        if name not in SENSORS and name not in PRESET_PAIRS:
            ap.error(f"--sensors: unknown {name!r} (known: {', '.join([*SENSORS, *PRESET_PAIRS])})")
        frames = _pings(args.scene, args.seed, args.goals, args.pings, name)
        doc[name] = {v: measure(frames, v) for v in args.variants.split(",")}
        print(json.dumps({name: doc[name]}), flush=True)


if __name__ == "__main__":
    main()
