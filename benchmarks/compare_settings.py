"""Two settings of one config on the same recordings, run by run (a paired comparison).

For every scene and sensor of `bench_sensors` (the same recordings, made once), run the
baseline settings, then the candidate settings in the same store, so the stages the two
share are computed once and only what the candidate changes is run again. Prints, per
recording, `bench_sensors`' figures for both and the rows where a goal is met by one and
not the other; one JSON document on stdout. Costs are not compared (the second run reuses
the first's stages): use `bench_sensors` for CPU time and memory.

    .venv/bin/python -m benchmarks.compare_settings --scenes marina \\
        configs/scenes/frozen/ferry_slip.yaml --base classify.min_views=1 [--candidate k=v]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from benchmarks.bench_sensors import OUT, PRESETS, SENSORS, _derived, _figures, _meets, _recording

KEYS = ("standard_m", "semantic_over_standard", "accurate_ratio", "semantic_over_clean",
        "piling_precision", "piling_recall")  # fmt: skip


def _run(dataset: Path, store: Path, sets: list[str]) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "sonarmap.pipeline", "run", str(dataset), "--store", str(store)]
    cmd += ["--json", "-q", "--no-figures", "-j", "1"]
    cmd += [a for s in sets for a in ("--set", s)]
    env = {**os.environ, "SONARMAP_CACHE_DIR": str(OUT / "cache")}
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    if done.returncode:
        raise SystemExit(f"{dataset.name}: sonarmap run failed: {done.stderr.strip()[-300:]}")
    return json.loads(done.stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", nargs="+", required=True)
    every = [*SENSORS, *PRESETS]
    ap.add_argument("--sensors", nargs="+", default=every, choices=every)
    ap.add_argument("--goals", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--base", action="append", default=[], help="section.field=value")
    ap.add_argument("--candidate", action="append", default=[], help="section.field=value")
    args = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    for scene in args.scenes:
        clean: dict[str, dict[str, Any]] = {}
        for sensor in args.sensors:
            rec = _recording(scene, sensor, args.goals, args.seed)
            store = Path(tempfile.mkdtemp(prefix="paired-", dir=OUT))
            try:
                pair = {
                    side: _figures(_run(rec, store, sets), 0.0, 0.0)
                    for side, sets in (("base", args.base), ("candidate", args.candidate))
                }
            finally:
                shutil.rmtree(store)
            for side, fig in pair.items():
                if sensor == "clean":
                    clean[side] = fig
                fig.update(_derived(fig, clean.get(side)))
            row = {"scene": Path(scene).stem, "sensor": sensor, **pair}
            rows.append(row)
            cells = "  ".join(
                f"{k} {pair['base'][k]}->{pair['candidate'][k]}" for k in KEYS
            )
            print(f"{row['scene']:14s} {sensor:13s} {cells}", file=sys.stderr, flush=True)
    met = {
        side: {k: sum(bool(_meets(k, r[side][k])) for r in rows) for k in KEYS}
        for side in ("base", "candidate")
    }
    print("rows meeting each goal, base -> candidate: "
          + ", ".join(f"{k} {met['base'][k]} -> {met['candidate'][k]}" for k in KEYS),
          file=sys.stderr)  # fmt: skip
    json.dump({"base": args.base, "candidate": args.candidate, "rows": rows, "met": met},
              sys.stdout, indent=1)  # fmt: skip
    print()


if __name__ == "__main__":
    main()
