"""Live view overhead: a whole run with the live server up and no client connected,
against the same run without it (target: at most 5 % more time).

    .venv/bin/python benchmarks/live_overhead.py [RECORDING] [--repeat 3]

Default recording: the tiny scene, seed 2, 45 s, simulated into data/bench. After one
warm-up run of each kind, each repetition runs every stage on a fresh store (the
classifier copied from the model cache), alternating without / with the live server so
that machine load hits both alike; reports the median wall and CPU seconds of each and
the relative overhead.

Measured 2026-12-02 (2 shared cores, load from other users), `--repeat 5`: without
6.15 s wall / 2.31 s CPU, with the server and no client 5.64 s / 2.23 s: -8.3 % wall,
-3.4 % CPU, i.e. below the noise (an earlier `--repeat 3` read +7.9 % / +14.9 %, the
other way). With no client nothing is built; the server itself costs about 1 ms to
start and stop and 0.2 ms CPU per idle second.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from sonarmap.pipeline.api import RunRequest, run_dataset
from sonarmap.pipeline.live.session import live_session

ROOT = Path(__file__).resolve().parents[1]


def _recording(path: str | None) -> Path:
    if path:
        return Path(path)
    from sonarmap.pipeline.training.datasets import Simulation, ensure_simulations, scene_path

    out = ROOT / "data" / "bench" / "tiny-seed2-45s.mcap"
    ensure_simulations([Simulation(scene_path("tiny"), 2, out, duration_s=45.0)], 1)
    return out


def _timed_run(recording: Path, live: bool) -> tuple[float, float]:
    with tempfile.TemporaryDirectory() as tmp:
        request = RunRequest(recording, store_dir=Path(tmp) / "store")
        wall, cpu = time.perf_counter(), time.process_time()
        if live:
            with live_session(True, port=0, linger=False) as view:
                run_dataset(request, on_stage=view.chain(lambda r: None))
        else:
            run_dataset(request, on_stage=lambda r: None)
        return time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", nargs="?", default=None)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    recording = _recording(args.recording)
    for live in (False, True):  # warm-up: imports (the SDK's too), model cache, page cache
        _timed_run(recording, live)
    runs: dict[bool, list[tuple[float, float]]] = {False: [], True: []}
    for _ in range(args.repeat):
        for live in (False, True):
            runs[live].append(_timed_run(recording, live))
    med = {
        k: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v))
        for k, v in runs.items()
    }
    print(f"recording: {recording} ({args.repeat} runs each, medians)")
    for live, (w, c) in med.items():
        print(
            f"{'live, no client' if live else 'no live view':16s} wall {w:7.2f} s  cpu {c:7.2f} s"
        )
    print(
        f"overhead: wall {100 * (med[True][0] / med[False][0] - 1):+.1f} %, "
        f"cpu {100 * (med[True][1] / med[False][1] - 1):+.1f} % (target <= 5 %)"
    )


if __name__ == "__main__":
    main()
