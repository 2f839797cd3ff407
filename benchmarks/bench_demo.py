"""`sonarmap demo` on a new machine: seconds, with the shipped model and with training.

Issue 22's `make demo` row (goal <= 100 s, environment already built). Each run gets a
fresh temporary folder for the recording, the store and `training.directory`, so it
simulates the marina and builds every stage as a first run on a new machine would:

- "shipped": the default, where the model comes from `configs/model` (no training
  scenes simulated, nothing trained);
- "training" (`--with-training`): `training.shipped_models=null`, so the harbour and the
  pier are simulated beside the marina and the model is trained, as before the model
  was shipped.

Prints one JSON object with each mode's seconds (median of `--repeat`) and the goal.

    .venv/bin/python benchmarks/bench_demo.py [--repeat 3] [--with-training]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
GOAL_S = 100.0
NOW_S = 203.0
"""Issue 22's "now": `make demo` cold with the environment built."""


def _one_demo(shipped: bool) -> dict[str, float | str]:
    with tempfile.TemporaryDirectory(prefix="bench-demo-") as tmp:
        root = Path(tmp)
        overrides = [f"training.directory={root / 'training'}"]
        if not shipped:
            overrides.append("training.shipped_models=null")
        cmd = [sys.executable, "-m", "sonarmap.pipeline", "demo", "--out", str(root / "demo")]
        cmd += ["--store", str(root / "store"), "--json"]
        for item in overrides:
            cmd += ["--set", item]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, check=True)
        seconds = time.perf_counter() - t0
        doc = json.loads(proc.stdout)
    return {"seconds": round(seconds, 1), "model_source": doc["summary"]["model"]["source"]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--with-training", action="store_true")
    args = parser.parse_args()
    modes = {"shipped": True} | ({"training": False} if args.with_training else {})
    out: dict[str, object] = {"load_average_1min": round(os.getloadavg()[0], 2)}
    for name, shipped in modes.items():
        runs = [_one_demo(shipped) for _ in range(args.repeat)]
        out[name] = {
            "demo_s": statistics.median(float(r["seconds"]) for r in runs),
            "demo_s_goal": f"<= {GOAL_S:g}",
            "runs_s": [r["seconds"] for r in runs],
            "model_source": sorted({str(r["model_source"]) for r in runs}),
        }
    out["now_s"] = NOW_S
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
