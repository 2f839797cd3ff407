"""Keyframe extraction speed and memory (issue 4 and issue 22 targets).

Targets: at least 2,000 sonar frame pairs scanned per second (issue 22; keyframes at 2 m
spacing; 404 pairs/s before it), and peak memory flat in recording length (a 3,000-pair
recording under 500 MB RSS). Speed is the median of `REPS` runs, wall and CPU time:
`keyframe_pairs_per_s` for the whole stage (open, choose the keyframes, write their
images to keyframes.mcap), `keyframe_scan_pairs_per_s` up to the keyframes chosen.

Two file layouts are measured: "sonarmap" (what the simulator and `sonarmap convert`
write: navigation in chunks apart from the images, so finding the keyframes
decompresses no image) and "interleaved" (one chunk stream, as most recorders write:
reading the navigation decompresses every chunk, so the file's size bounds the speed).

A recording like the simulator's (512 beams x 600 range bins per sonar, 2 Hz, vehicle
at 0.5 m/s, odometry at every ping) is written with `Ros2McapWriter`; its images are
simulator pings (tiny scene) reused cyclically, so zstd sees realistic content. Each
measurement runs in a fresh subprocess: open the recording, run the keyframes stage,
and stream its frames into keyframes.mcap with `write_frames` (what the engine does).
Peak RSS is that subprocess's ru_maxrss.

    .venv/bin/python -m benchmarks.bench_keyframes            # all figures
    .venv/bin/python -m benchmarks.bench_keyframes --one PATH # one measurement (internal)
"""

from __future__ import annotations

import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from sonarmap.schemas.sonar import SonarPing

ROOT = Path(__file__).resolve().parent.parent

RATE_HZ, SPEED = 2.0, 0.5
REPS = 3
# "now": issue 22's figure (an idle machine); on a loaded one compare CPU figures, or run
# the old commit in the same session (wall time moves with the load, not the code).
GOAL_PAIRS_PER_S, NOW_PAIRS_PER_S = 2000.0, 404.0
GOAL_PEAK_RSS_MB = 500.0
LAYOUTS = ("sonarmap", "interleaved")


def _bank(n: int = 8) -> list[tuple[SonarPing, SonarPing]]:
    """Ping pairs rendered by the simulator (tiny scene), reused cyclically."""
    from sonarmap.sim.config import SimConfig
    from sonarmap.sim.dataset import simulate
    from sonarmap.sim.scene import load_scene

    run = simulate(load_scene(ROOT / "configs" / "scenes" / "tiny.yaml"), SimConfig(), 0)
    picks = np.linspace(0, run.n_frames - 1, n).astype(int)
    return [(f.horizontal, f.vertical) for f in (run.frame(int(i)) for i in picks)]


def write_recording(path: Path, n_pairs: int, labels: bool, layout: str = "sonarmap") -> None:
    """A 2 Hz recording: odometry and both sonars at every ping, vehicle at 0.5 m/s on a
    circle of 50 m radius; with `labels`, also the label and truth-angle images."""
    from dataclasses import replace

    from sonarmap.pipeline.formats.frames_io import image_message, sonar_message
    from sonarmap.pipeline.formats.rosmsg import Ros2McapWriter, recording_writer
    from sonarmap.schemas.topics import (
        IMAGE_TYPE,
        LABEL_TOPIC,
        ODOMETRY_TYPE,
        PROJECTED_SONAR_TYPE,
        SONAR_TOPIC,
        TOPIC_DEAD_RECKONING,
        TRUTH_ANGLE_TOPIC,
    )
    from tests.fixtures import odometry

    bank = _bank()
    t0 = 1_700_000_000_000_000_000
    radius = 50.0
    with (
        path.open("wb") as f,
        recording_writer(f) if layout == "sonarmap" else Ros2McapWriter(f) as w,
    ):
        for k in range(n_pairs):
            t = t0 + round(k * 1e9 / RATE_HZ)
            a = SPEED * (k / RATE_HZ) / radius
            xyz = np.array([radius * np.sin(a), radius * (1 - np.cos(a)), -2.0])
            odom = odometry(t, xyz, np.array([0.0, 0.0, np.sin(a / 2), np.cos(a / 2)]))
            w.write(TOPIC_DEAD_RECKONING, ODOMETRY_TYPE, odom, t)
            for ping in bank[k % len(bank)]:
                s = ping.sonar
                w.write(
                    SONAR_TOPIC[s], PROJECTED_SONAR_TYPE, sonar_message(replace(ping, t_ns=t), s), t
                )
                if labels:
                    assert ping.labels is not None and ping.truth_angle_rad is not None
                    w.write(LABEL_TOPIC[s], IMAGE_TYPE, image_message(ping.labels, t, s), t)
                    truth = image_message(ping.truth_angle_rad.astype(np.float32), t, s)
                    w.write(TRUTH_ANGLE_TOPIC[s], IMAGE_TYPE, truth, t)


def measure_one(path: Path) -> dict[str, float]:
    from sonarmap.pipeline.formats.frames_io import write_frames
    from sonarmap.pipeline.readers import open_recording
    from sonarmap.stages.keyframes import STAGE, KeyframesConfig

    cfg = KeyframesConfig(spacing_m=2.0)
    t0, c0 = time.perf_counter(), time.process_time()
    rec = open_recording(path, cfg)
    out = STAGE.run(cfg, {"dataset": rec})
    # The keyframes are chosen here (the frames are a lazy stream): the scan proper.
    scan_s, scan_cpu = time.perf_counter() - t0, time.process_time() - c0
    with tempfile.TemporaryDirectory() as tmp:
        n_kf = write_frames(out["frames"], Path(tmp) / "keyframes.mcap")
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    pairs = out["sensors"]["pairing"]["pairs"]
    return {
        "pairs": pairs,
        "keyframes": n_kf,
        "scan_pairs_per_s": round(pairs / scan_s, 1),
        "scan_pairs_per_cpu_s": round(pairs / scan_cpu, 1),
        "seconds": round(seconds, 3),
        "pairs_per_s": round(pairs / seconds, 1),
        "cpu_s": round(cpu, 3),
        "pairs_per_cpu_s": round(pairs / cpu, 1),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }


def _run_child(path: Path) -> dict[str, float]:
    proc = subprocess.run(
        [sys.executable, "-m", "benchmarks.bench_keyframes", "--one", str(path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
        env={"PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"},
    )
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _median(runs: list[dict[str, float]], key: str) -> float:
    return float(statistics.median(r[key] for r in runs))


def _measure(path: Path, reps: int) -> dict[str, object]:
    runs = [_run_child(path) for _ in range(reps)]
    print(json.dumps({path.name: runs}), file=sys.stderr, flush=True)
    keys = ("pairs_per_s", "pairs_per_cpu_s", "seconds", "cpu_s", "peak_rss_mb")
    keys += ("scan_pairs_per_s", "scan_pairs_per_cpu_s")
    return {**{k: _median(runs, k) for k in keys}, "file_mb": round(path.stat().st_size / 1e6, 1)}


def main() -> None:
    figures: dict[str, dict[str, object]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        cases = [(3000, False, layout, REPS) for layout in LAYOUTS]
        cases += [
            (300, False, "sonarmap", 1),
            (300, True, "sonarmap", 1),
            (3000, True, "sonarmap", 1),
        ]
        for n, labels, layout, reps in cases:
            path = Path(tmp) / f"rec_{n}_{int(labels)}_{layout}.mcap"
            write_recording(path, n, labels, layout)
            name = f"{n}_pairs{'_with_labels' if labels else ''}_{layout}"
            figures[name] = _measure(path, reps)
            path.unlink()
    big, small = figures["3000_pairs_sonarmap"], figures["300_pairs_sonarmap"]
    print(
        json.dumps(
            {
                "keyframe_pairs_per_s": big["pairs_per_s"],
                "keyframe_pairs_per_s_goal": GOAL_PAIRS_PER_S,
                "keyframe_pairs_per_s_now": NOW_PAIRS_PER_S,
                "keyframe_pairs_per_cpu_s": big["pairs_per_cpu_s"],
                "keyframe_scan_pairs_per_s": big["scan_pairs_per_s"],
                "keyframe_scan_pairs_per_s_goal": GOAL_PAIRS_PER_S,
                "keyframe_scan_pairs_per_cpu_s": big["scan_pairs_per_cpu_s"],
                "keyframe_pairs_per_s_interleaved": figures["3000_pairs_interleaved"][
                    "pairs_per_s"
                ],
                "keyframe_pairs_per_cpu_s_interleaved": figures["3000_pairs_interleaved"][
                    "pairs_per_cpu_s"
                ],
                "peak_rss_mb_3000_pairs": big["peak_rss_mb"],
                "peak_rss_mb_3000_pairs_with_labels": figures["3000_pairs_with_labels_sonarmap"][
                    "peak_rss_mb"
                ],
                "peak_rss_mb_3000_pairs_goal": GOAL_PEAK_RSS_MB,
                "peak_rss_mb_300_pairs": small["peak_rss_mb"],
                "reps": REPS,
                "details": figures,
            }
        )
    )


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--one":
        print(json.dumps(measure_one(Path(sys.argv[2]))))
    else:
        main()
