"""Cost of checking every MCAP chunk (decompression, size, CRC) when a recording is opened.

`McapSource` decompresses and CRC-checks every chunk once at open (issue 23), also chunks
the keyframes stage then skips. This measures, on a `bench_keyframes` recording (both
sonars with label images, 2 Hz), the check alone and the keyframes stage with the check
on and off (best of `REPEATS`, each in a fresh store).

    .venv/bin/python -m benchmarks.bench_mcap_verify [N_PAIRS]
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

REPEATS = 2


def _keyframes_s(path: Path, store: Path, verify: bool) -> float:
    from sonarmap.pipeline.api import RunRequest, run_dataset
    from sonarmap.pipeline.readers import mcap_source

    original = mcap_source._McapFile.verify
    if not verify:
        mcap_source._McapFile.verify = lambda self: None  # type: ignore[method-assign]
    try:
        t0 = time.perf_counter()
        run_dataset(RunRequest(path, store_dir=store, until="keyframes"))
        return time.perf_counter() - t0
    finally:
        mcap_source._McapFile.verify = original  # type: ignore[method-assign]


def main() -> None:
    from benchmarks.bench_keyframes import write_recording
    from sonarmap.pipeline.readers.mcap_source import _McapFile

    n_pairs = int(sys.argv[1]) if len(sys.argv) > 1 else 600
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "rec.mcap"
        write_recording(path, n_pairs, labels=True)
        f = _McapFile(path)
        t0 = time.perf_counter()
        f.verify()
        check_s = time.perf_counter() - t0
        runs = {
            mode: min(
                _keyframes_s(path, Path(tmp) / f"store-{mode}-{i}", mode == "on")
                for i in range(REPEATS)
            )
            for mode in ("off", "on")
        }
        doc = {
            "n_pairs": n_pairs,
            "file_mb": round(path.stat().st_size / 1e6, 1),
            "uncompressed_mb": round(sum(c.uncompressed_size for c in f.chunks) / 1e6, 1),
            "chunks": len(f.chunks),
            "check_s": round(check_s, 3),
            "check_mb_per_s": round(sum(c.uncompressed_size for c in f.chunks) / 1e6 / check_s),
            "keyframes_check_off_s": round(runs["off"], 3),
            "keyframes_check_on_s": round(runs["on"], 3),
            "overhead_pct": round(100 * (runs["on"] / runs["off"] - 1), 1),
        }
    print(json.dumps(doc, indent=2))


if __name__ == "__main__":
    main()
