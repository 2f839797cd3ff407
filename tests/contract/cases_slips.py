"""A user's slips that must destroy nothing and repeat nothing.

- `convert -o` / `simulate -o` onto a FIFO, a folder, a symbolic link or the input itself:
  refused before any work, the entry left as it was;
- `gc --store` on a folder that is not a store, or with a run record it cannot read:
  refused, nothing removed;
- `follow` on a folder of ROS 1 bags: refused before the live view starts (it used to
  wait forever);
- `sweep` lists that would count one point twice (a repeated value, a dataset given
  twice, a key swept twice or also fixed): refused before the first run.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

from tests.contract.case import Case, Check, names
from tests.fixtures import small_recording


def _rec(work: Path) -> Path:
    # Seed 2, 15 s: the smallest tiny-scene mission whose map is not empty.
    return small_recording(work / "recs" / "dive.mcap", seed=2, duration_s=15.0)


def _untouched(*paths: str) -> Check:
    """Check: the error names the path and each listed entry is still there as it was."""

    def check(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
        gone = [p for p in paths if not os.path.lexists(work / p)]
        return f"removed or replaced: {gone}" if gone else names(paths[0])(work, done)

    return check


def _convert_onto_input(work: Path) -> list[str]:
    _rec(work)
    return ["convert", "recs/dive.mcap", "-o", "recs/dive.mcap"]


def _convert_onto_fifo(work: Path) -> list[str]:
    _rec(work)
    os.mkfifo(work / "out.fifo")
    return ["convert", "recs/dive.mcap", "-o", "out.fifo"]


def _convert_onto_folder(work: Path) -> list[str]:
    _rec(work)
    (work / "results").mkdir()
    (work / "results" / "mine.csv").write_text("mine")
    return ["convert", "recs/dive.mcap", "-o", "results"]


def _simulate_onto_link(work: Path) -> list[str]:
    (work / "precious.txt").write_text("keep me")
    (work / "link.mcap").symlink_to("precious.txt")
    return ["simulate", "-o", "link.mcap", "--goals", "1", "-q"]


def _link_kept(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    if not (work / "link.mcap").is_symlink() or (work / "precious.txt").read_text() != "keep me":
        return "the link or its target was replaced"
    return names("link.mcap")(work, done)


def _gc_not_a_store(work: Path) -> list[str]:
    for sub in ("evaluate/2024", "train/001"):
        (work / "proj" / sub).mkdir(parents=True)
        (work / "proj" / sub / "results.csv").write_text("mine")
    return ["gc", "--store", "proj"]


def _gc_unreadable_record(work: Path) -> list[str]:
    from tests.contract.cases_cli import _sonarmap

    _rec(work)
    done = _sonarmap(work, "run", "recs/dive.mcap", "--until", "keyframes", "--store", "st")
    assert done.returncode == 0, done.stderr[-500:]
    for record in (work / "st" / "runs").glob("*.json"):
        record.write_bytes(b"")
    return ["gc", "--store", "st"]


def _artifacts_kept(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    if not list((work / "st").glob("keyframes/*/manifest.json")):
        return "gc removed the artifacts"
    return names("unreadable run record")(work, done)


def _follow_ros1_folder(work: Path) -> list[str]:
    (work / "dive").mkdir()
    (work / "dive" / "dive.bag").write_bytes(b"#ROSBAG V2.0\n" + bytes(64))
    return ["follow", "dive", "--port", "0", "-q"]


def _sweep_repeated_value(work: Path) -> list[str]:
    _rec(work)
    return ["sweep", "recs/dive.mcap", "-s", "keyframes.spacing_m=2,3,2.0"]


def _sweep_dataset_twice(work: Path) -> list[str]:
    _rec(work)
    return ["sweep", "recs/dive.mcap", "./recs/dive.mcap", "-s", "keyframes.spacing_m=2"]


def _sweep_fixed_and_swept(work: Path) -> list[str]:
    _rec(work)
    return ["sweep", "recs/dive.mcap", "-s", "keyframes.spacing_m=2,3",
            "--fix", "keyframes.spacing_m=4"]  # fmt: skip


CASES = [
    Case("data loss", "convert -o onto its own input", _convert_onto_input,
         check=_untouched("recs/dive.mcap"), max_seconds=20.0),
    Case("data loss", "convert -o onto a FIFO", _convert_onto_fifo,
         check=_untouched("out.fifo"), max_seconds=20.0),
    Case("data loss", "convert -o onto a folder", _convert_onto_folder,
         check=_untouched("results", "results/mine.csv"), max_seconds=20.0),
    Case("data loss", "simulate -o onto a symbolic link", _simulate_onto_link, check=_link_kept),
    Case("data loss", "gc --store on a folder that is not a store", _gc_not_a_store,
         check=_untouched("proj", "proj/evaluate/2024/results.csv", "proj/train/001/results.csv")),
    Case("data loss", "gc with an empty run record", _gc_unreadable_record, check=_artifacts_kept,
         max_seconds=20.0),
    Case("exit codes", "follow on a folder of ROS 1 bags", _follow_ros1_folder,
         check=names("dive", "ROS 1 bag")),
    Case("exit codes", "sweep with a value given twice", _sweep_repeated_value,
         check=names("given twice"), max_seconds=20.0),
    Case("exit codes", "sweep with a dataset given twice", _sweep_dataset_twice,
         check=names("given twice"), max_seconds=20.0),
    Case("exit codes", "sweep with a key both swept and fixed", _sweep_fixed_and_swept,
         check=names("also swept"), max_seconds=20.0),
]  # fmt: skip
