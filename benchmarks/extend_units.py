"""What per-keyframe work units save (issue 53): an extended and a trimmed recording run on
the store of the base, against cold runs on fresh stores; and a keyframe-spacing sweep
against its points run cold one by one. (Not a `bench_*.py`: it takes recordings, so
`make bench`'s `run_all.py` does not run it.)

Each run is a child `sonarmap run REC --store S -j 1 --json`; its CPU time (user + sys)
and peak RSS come from `os.wait4`. For every run on the shared store the table says which
stages were hits, how many work units each computing stage reused, and whether every
artifact's files equal (sha256) the cold run's of the same recording.

    python benchmarks/extend_units.py --base m8_base.mcap --extended m8_full.mcap \\
        --trimmed m8_trim.mcap --work /tmp/bench_extend [--sweep]

The recordings: `sonarmap simulate -o m8_full.mcap --goals 8 --seed 0 -j 2` (extended),
then `--cut m8_full.mcap` writes the base (cut at 1/1.1 of its length) and the trimmed
(0.9 of the base) beside it, by log time with the mcap library. (`simulate --duration-s`
does not make a prefix: the cut mission's trajectory differs from the first ping on.)
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

SONARMAP = [sys.executable, "-m", "sonarmap.pipeline"]


def child(args: list[str]) -> dict[str, Any]:
    """Run one child: its JSON document, stderr, CPU seconds (user + sys), peak RSS [MB]
    and wall seconds (`os.wait4`: this child's own figures)."""
    import tempfile

    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(args, stdout=out, stderr=err, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - t0
        out.seek(0)
        err.seek(0)
        text, log = out.read(), err.read()
    if proc.returncode:
        sys.exit(f"{' '.join(args)} failed:\n{log[-2000:]}")
    try:
        doc = json.loads(text)
    except ValueError:  # `sweep` prints a table, not JSON
        doc = {}
    return {
        "doc": doc,
        "stderr": log,
        "wall_s": wall,
        "cpu_s": round(usage.ru_utime + usage.ru_stime, 2),
        "peak_rss_mb": round(usage.ru_maxrss / 1024),
    }


def run(rec: Path, store: Path, extra: tuple[str, ...] = ()) -> dict[str, Any]:
    return child([*SONARMAP, "run", str(rec), "--store", str(store), "-j", "1", "--json", *extra])


def cut_mcap(src: Path, dst: Path, seconds: float) -> int:
    """Copy the messages of `src` logged in its first `seconds` (schemas, channels,
    attachments and metadata kept; the metadata's `n_frames` set to the horizontal pings
    kept) to `dst`; returns the messages written."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with src.open("rb") as f_in, dst.open("wb") as f_out:
        reader = make_reader(f_in)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        end = summary.statistics.message_start_time + int(seconds * 1e9)
        header = reader.get_header()
        writer = Writer(f_out)
        writer.start(profile=header.profile, library=header.library)
        schema_ids = {
            sid: writer.register_schema(s.name, s.encoding, s.data)
            for sid, s in summary.schemas.items()
        }
        channel_ids = {
            cid: writer.register_channel(c.topic, c.message_encoding, schema_ids[c.schema_id], c.metadata)
            for cid, c in summary.channels.items()
        }  # fmt: skip
        n = frames = 0
        for _, channel, msg in reader.iter_messages(ending_at=end, log_time_order=True):
            writer.add_message(
                channel_ids[channel.id], msg.log_time, msg.data, msg.publish_time, msg.sequence
            )
            n += 1
            frames += channel.topic == "/sonar/horizontal"
        for a in reader.iter_attachments():
            writer.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        for m in reader.iter_metadata():
            meta = dict(m.metadata)
            if "n_frames" in meta:
                meta["n_frames"] = str(frames)
            writer.add_metadata(m.name, meta)
        writer.finish()
    return n


def _files(stage: dict[str, Any]) -> dict[str, str]:
    manifest = json.loads((Path(stage["path"]) / "manifest.json").read_text())
    return {name: f["sha256"] for name, f in manifest["files"].items()}


def compare(warm: dict[str, Any], cold: dict[str, Any]) -> list[str]:
    """Stages whose files differ between two runs of the same recording."""
    cold_stages = {s["stage"]: s for s in cold["doc"]["stages"]}
    return [
        s["stage"] for s in warm["doc"]["stages"] if _files(s) != _files(cold_stages[s["stage"]])
    ]


def describe(name: str, got: dict[str, Any], cold_cpu: float | None = None) -> str:
    stages = got["doc"].get("stages", [])
    hits = [s["stage"] for s in stages if s["status"] == "hit"]
    units = ", ".join(
        f"{s['stage']} {s['units'][0]}/{sum(s['units'])}" for s in stages if s.get("units")
    )
    share = f" ({100 * got['cpu_s'] / cold_cpu:.0f} % of cold)" if cold_cpu else ""
    return (
        f"{name:<28} cpu {got['cpu_s']:6.1f} s{share}  peak {got['peak_rss_mb']:5.0f} MB"
        f"  wall {got['wall_s']:5.1f} s  hits [{', '.join(hits)}]  units reused [{units}]"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cut", type=Path, help="write <stem>_base.mcap, <stem>_trim.mcap, exit")
    ap.add_argument("--base", type=Path)
    ap.add_argument("--extended", type=Path)
    ap.add_argument("--trimmed", type=Path)
    ap.add_argument("--work", type=Path, help="stores go here (emptied)")
    ap.add_argument("--sweep", action="store_true", help="also the spacing sweep")
    ap.add_argument("--sweep-only", action="store_true", help="only the spacing sweep (--base)")
    ap.add_argument("--spacings", default="2,3,4,6")
    args = ap.parse_args()
    if args.cut is not None:
        from mcap.reader import make_reader

        with args.cut.open("rb") as f:
            stats = make_reader(f).get_summary().statistics  # type: ignore[union-attr]
        length = (stats.message_end_time - stats.message_start_time) / 1e9
        for name, seconds in (("base", length / 1.1), ("trim", 0.9 * length / 1.1)):
            out = args.cut.with_name(f"{args.cut.stem}_{name}.mcap")
            print(f"{out}: first {seconds:.1f} s, {cut_mcap(args.cut, out, seconds)} messages")
        return
    shutil.rmtree(args.work, ignore_errors=True)
    args.work.mkdir(parents=True)
    if not args.sweep_only:
        extend_and_trim(args)
    if args.sweep or args.sweep_only:
        spacing_sweep(args)


def extend_and_trim(args: argparse.Namespace) -> None:
    shared = args.work / "shared"
    base = run(args.base, shared)
    print(describe("base, cold", base), flush=True)
    ext = run(args.extended, shared)
    trim = run(args.trimmed, shared)
    ext_cold = run(args.extended, args.work / "ext_cold")
    trim_cold = run(args.trimmed, args.work / "trim_cold")
    print(describe("extended, on base's store", ext, ext_cold["cpu_s"]))
    print(describe("extended, cold", ext_cold))
    print(describe("trimmed, on base's store", trim, trim_cold["cpu_s"]))
    print(describe("trimmed, cold", trim_cold))
    print(f"extended: stages differing from cold: {compare(ext, ext_cold) or 'none'}")
    print(f"trimmed: stages differing from cold: {compare(trim, trim_cold) or 'none'}")


def spacing_sweep(args: argparse.Namespace) -> None:
    sweep = child(
        [*SONARMAP, "sweep", str(args.base), "--set", f"keyframes.spacing_m={args.spacings}",
         "-j", "1", "--store", str(args.work / "sweep"), "--out", str(args.work / "sweep_out")]
    )  # fmt: skip
    sweep_cpu = sweep["cpu_s"]
    lines = [line for line in sweep["stderr"].splitlines() if line.startswith("ok ")]
    cold_cpu = 0.0
    for value in args.spacings.split(","):
        one = run(args.base, args.work / f"cold_{value}", ("--set", f"keyframes.spacing_m={value}"))
        cold_cpu += one["cpu_s"]
    print(f"sweep {args.spacings}: cpu {sweep_cpu:.1f} s against {cold_cpu:.1f} s cold one by"
          f" one ({100 * sweep_cpu / cold_cpu:.0f} %)")  # fmt: skip
    print("\n".join(f"  {line}" for line in lines))


if __name__ == "__main__":
    main()
