"""`sonarmap follow` on a mission written at its own pace: how far behind the newest
keyframe the map on the Foxglove socket is (issue 53's target: at most 2 s on 2 cores).

    .venv/bin/python -m benchmarks.bench_follow [RECORDING] [--goals 8] [--speed 1]

Default recording: the marina, seed 0, 8 goals, simulated into data/bench. One process
writes it again (`sonarmap.pipeline.live.replay`: the `mcap` Writer, 4 KiB chunks,
flushed, each message when its log time comes, divided by --speed) and stamps each sonar
ping with the wall clock when it reached the file; `sonarmap follow` maps it in another;
a Foxglove client here receives the maps. A map's log time is its newest keyframe's, so
its lag is its arrival at the client less the time the writer wrote that ping (counted
for the first map holding that keyframe; later ones hold it too). Then a
batch `run` of the finished file in a fresh store: the same keys and bytes are checked.

Measured 2026-12-06 (2 shared cores, load average 1.9-2.0), default arguments: lag of the
preview (`/map/preview`, the first holding each new keyframe) median 1.21 s, p90 1.45 s,
max 2.21 s (98 of 99 within the 2 s target); lag of the full map (`/map/standard`)
median 10.6 s, max 42.6 s, 35 updates (compute median 7.8 s, the last 35.2 s), the
final map 48.1 s after the file was closed, the final artifacts equal to the batch
run's. Each full update was then a cold run of the recording so far.

Again 2026-12-07, with the per-keyframe work units (`bench_follow /tmp/m8_full.mcap`, the
same mission; load average 0.4-1.0): preview lag median 0.86 s, p90 0.99 s, max 1.41 s
(99 of 99 within 2 s); full map lag median 9.5 s, p90 19.1 s, max 26.3 s, 58 updates
(compute median 5.0 s, the last 27.0 s: the calibration's period doubled), the final map
29.5 s after close, the final artifacts equal to the batch run's.
"""

from __future__ import annotations

import argparse
import asyncio
import bisect
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from contextlib import suppress
from pathlib import Path
from typing import Any

from sonarmap.pipeline.api import RunRequest, run_dataset

ROOT = Path(__file__).resolve().parents[1]


def _recording(path: str | None, goals: int, seed: int) -> Path:
    if path:
        return Path(path)
    from sonarmap.pipeline.training.datasets import Simulation, ensure_simulations, scene_path

    out = ROOT / "data" / "bench" / f"marina-seed{seed}-g{goals}.mcap"
    ensure_simulations([Simulation(scene_path("marina"), seed, out, goals=goals)], 1)
    return out


def _client(url: str, follow: subprocess.Popen[bytes]) -> dict[str, list[tuple[float, int]]]:
    """Per map topic, (arrival wall clock, log time) of each message until follow ends
    (/map/preview: only those holding points; an empty one clears the preview)."""
    sys.path.insert(0, str(ROOT / "tests"))  # the test suite's minimal Foxglove client
    import websockets
    from foxglove_ws_client import Received, collect

    seen: list[Received] = []

    def until(g: Received) -> bool:
        seen[:] = [g]
        return follow.poll() is not None

    with suppress(websockets.ConnectionClosed):
        asyncio.run(collect(url, until, timeout_s=3600.0))
    offset = time.time() - time.monotonic()
    got = seen[-1].messages if seen else {}
    return {
        topic: [(a + offset, t) for a, t, msg in got.get(topic, []) if len(msg.data) or not keep]
        for topic, keep in (("/map/standard", False), ("/map/preview", True))
    }


def _first_lags(
    maps: list[tuple[float, int]], written: Any, done: float
) -> list[tuple[float, int]]:
    """(lag, newest keyframe time) of the first map holding each new newest keyframe,
    while the file was written."""
    first: dict[int, float] = {}
    for a, t in maps:
        first.setdefault(t, a)
    return [(a - written(t), t) for t, a in sorted(first.items()) if a < done]


def _stats(lags: list[float], prefix: str) -> dict[str, Any]:
    return {
        f"{prefix}_s_median": round(statistics.median(lags), 2) if lags else None,
        f"{prefix}_s_p90": round(statistics.quantiles(lags, n=10)[-1], 2)
        if len(lags) > 1
        else None,
        f"{prefix}_s_max": round(max(lags), 2) if lags else None,
        f"{prefix}_count": len(lags),
    }


def _artifacts(store: Path, keys: dict[str, str]) -> dict[str, dict[str, str]]:
    import hashlib

    return {
        s: {
            p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted((store / s / k).iterdir())
            if p.name != "manifest.json"
        }
        for s, k in keys.items()
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", nargs="?", default=None)
    parser.add_argument("--goals", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--speed", type=float, default=1.0)
    parser.add_argument("--every-s", type=float, default=2.0)
    parser.add_argument("-j", "--workers", type=int, default=None)
    parser.add_argument("--split-s", type=float, default=None, help="write a bag directory")
    args = parser.parse_args()
    source = _recording(args.recording, args.goals, args.seed)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    jobs = [] if args.workers is None else ["-j", str(args.workers)]
    with tempfile.TemporaryDirectory(prefix="bench-follow-") as tmp:
        work = Path(tmp)
        growing, store = work / "dive", work / "store"
        split = [] if args.split_s is None else ["--split-s", str(args.split_s)]
        if split:
            growing.mkdir()
        else:
            growing = growing.with_suffix(".mcap")
            growing.write_bytes(b"")
        err_log, wrote_log = work / "follow.err", work / "writer.out"
        with err_log.open("w") as err_f:
            follow = subprocess.Popen(
                [
                    *(sys.executable, "-m", "sonarmap.pipeline", "follow", str(growing)),
                    *("--store", str(store), "--port", "0", "--json"),
                    *("--every-s", str(args.every_s), *jobs),
                ],
                cwd=ROOT,
                env=env,
                stdout=subprocess.PIPE,
                stderr=err_f,
            )
            while not (m := re.search(r"live: (ws://[\d.:]+)", err_log.read_text())):
                if follow.poll() is not None:
                    sys.exit(f"follow ended: {err_log.read_text()}")
                time.sleep(0.1)
            with wrote_log.open("w") as w_f:
                writer = subprocess.Popen(
                    [
                        *(sys.executable, "-m", "sonarmap.pipeline.live.replay", str(source)),
                        *(str(growing), "--speed", str(args.speed), "--log-writes", *split),
                    ],
                    cwd=ROOT,
                    env=env,
                    stdout=w_f,
                )
                cpu0 = os.times()
                load0 = os.getloadavg()[0]
                topics = _client(m.group(1), follow)
                load1 = os.getloadavg()[0]
                maps = topics["/map/standard"]
                out, _ = follow.communicate()
                writer.wait()
                cpu1 = os.times()
        stderr = err_log.read_text()
        wrote = [ln.split() for ln in wrote_log.read_text().splitlines()]
        pings = sorted((int(t), float(w)) for k, t, w in wrote if k == "wrote")
        done = next(float(w) for k, _, w in wrote if k == "done")
        ping_t = [t for t, _ in pings]

        def written(t_ns: int) -> float:
            return pings[min(bisect.bisect_left(ping_t, t_ns), len(pings) - 1)][1]

        during = _first_lags(maps, written, done)
        previews = _first_lags(topics["/map/preview"], written, done)
        after = [a - done for a, _ in maps if a >= done]
        lags = [lag for lag, _ in during]
        computed = [float(x) for x in re.findall(r"computed in ([\d.]+) s", stderr)]
        doc = json.loads(out)
        keys = {s["stage"]: s["key"] for s in doc["stages"]}
        batch = work / "batch"
        t0 = time.perf_counter()
        result, _ = run_dataset(RunRequest(growing, store_dir=batch, workers=args.workers))
        batch_wall = time.perf_counter() - t0
        same_keys = keys == {s.stage: s.key for s in result.stages}
        same_bytes = same_keys and _artifacts(store, keys) == _artifacts(batch, keys)
    span_s = (ping_t[-1] - ping_t[0]) / 1e9
    figures = {
        "recording": str(source),
        "log_span_s": round(span_s, 1),
        "speed": args.speed,
        "write_wall_s": round(done - pings[0][1], 1),
        "maps_during_write": sum(1 for a, _ in maps if a < done),
        "new_keyframe_maps_during_write": len(during),
        "follow_updates": len(computed),
        "update_compute_s_median": round(statistics.median(computed), 2) if computed else None,
        "update_compute_s_last": computed[-1] if computed else None,
        **_stats(lags, "full_map_lag"),
        **_stats([lag for lag, _ in previews], "preview_lag"),
        "lag_s_goal": 2.0,
        "load_average_1min_start_end": [round(load0, 2), round(load1, 2)],
        "final_map_after_close_s": round(after[-1], 1) if after else None,
        "follow_and_writer_cpu_s": round(cpu1.children_user - cpu0.children_user, 1),
        "batch_run_wall_s": round(batch_wall, 1),
        "final_artifacts_equal_run": bool(same_bytes),
    }
    for lag, t in during:
        print(f"map with keyframes to t={(t - ping_t[0]) / 1e9:7.1f} s: lag {lag:6.2f} s")
    for lag, t in previews:
        print(f"preview with keyframes to t={(t - ping_t[0]) / 1e9:7.1f} s: lag {lag:6.2f} s")
    print(json.dumps(figures, indent=1))


if __name__ == "__main__":
    main()
