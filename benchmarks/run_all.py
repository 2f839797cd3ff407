"""Run every benchmark script (`bench_*.py`) and print one table of their JSON figures.

Each benchmark ends its stdout with one JSON object (on one line or indented). Results are also
written to `data/bench/results.json` so closing notes can cite them. Each runs from the repo root
as `python -m benchmarks.bench_NAME`, so that it can import `tests.fixtures`.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def _last_json(stdout: str) -> dict:
    """The JSON object that ends `stdout`: from the last unindented line opening one."""
    lines = stdout.rstrip().splitlines()
    starts = [i for i, ln in enumerate(lines) if ln.startswith("{")]
    return json.loads("\n".join(lines[starts[-1] :])) if starts else {}


def _flat(doc: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in doc.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def goal_rows(results: dict) -> list[str]:
    """`bench: figure = value (goal: g)` for every figure printed beside a `<figure>_goal`."""
    rows = []
    for name, doc in results.items():
        flat = _flat(doc)
        for key, goal in flat.items():
            base = key.removesuffix("_goal")
            if key.endswith("_goal") and base in flat:
                rows.append(f"{name:>16}: {base} = {flat[base]} (goal: {goal})")
    return rows


def main() -> int:
    only = sys.argv[1:]
    results = {}
    for script in sorted(HERE.glob("bench_*.py")):
        name = script.stem.removeprefix("bench_")
        if only and name not in only:
            continue
        t0 = time.perf_counter()
        proc = subprocess.run(
            [sys.executable, "-m", f"benchmarks.{script.stem}"],
            capture_output=True,
            text=True,
            cwd=ROOT,
        )
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            results[name] = {
                "error": proc.stderr.strip().splitlines()[-1:] or ["failed"],
                "wall_s": wall,
            }
        else:
            results[name] = {**_last_json(proc.stdout), "wall_s": round(wall, 1)}
        print(f"{name:>16}: {json.dumps(results[name])}", flush=True)
    print("\nfigures beside their goals:")
    for row in goal_rows(results):
        print(row)
    out = Path("data/bench")
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(results, indent=2, sort_keys=True))
    return 1 if any("error" in r for r in results.values()) else 0


if __name__ == "__main__":
    raise SystemExit(main())
