"""User paths, sweeps and JSON output at the CLI boundary.

- symlinked recordings in several layouts run and plan (exit 0), broken ones are refused;
- names over 255 characters, paths over PATH_MAX: one `error:` line naming the path;
- newlines, carriage returns, escapes, separators and undecodable bytes in paths never
  split the one-line error;
- read-only or full outputs (`--store`, `--out`): exit 2 naming the folder (root ignores
  chmod, so /sys, a read-only bind mount and a tiny tmpfs stand in, when mountable);
- sweeps over missing, empty, corrupt or truncated datasets: refused before the first
  run, or a non-zero exit after the others finished with their tables written;
- every `--json` output parses with a strict parser (no bare NaN / Infinity);
- a sweep's workers die with its process (kill -9 of the parent alone).
"""

from __future__ import annotations

import atexit
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from tests.contract.case import Case, error_line, names
from tests.fixtures import small_recording
from tests.fixtures.shared_data import SHARED_DATA

ROOT = Path(__file__).resolve().parents[2]
RUN_S = 150.0
"""Cases that map a recording (not a refusal) may take a real run's time."""


def _rec(work: Path, rel: str = "recs/dive.mcap") -> Path:
    # Seed 2, 15 s: the smallest tiny-scene mission whose map is not empty.
    return small_recording(work / rel, seed=2, duration_s=15.0)


def _sonarmap(work: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """A preparatory sonarmap call (not the case's own, which the campaign times)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "80"}
    return subprocess.run(
        [sys.executable, "-m", "sonarmap.pipeline", *args],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )


def _one_clean_line(done: subprocess.CompletedProcess[str]) -> str | None:
    """stderr holds nothing but the error line: no split, no raw control character."""
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    if len(lines) != 1:
        return f"{len(lines)} non-empty stderr lines: {lines[:3]!r}"
    bad = [c for c in lines[0] if ord(c) < 32 or c in "\x7f\u2028\u2029"]
    return f"raw control characters {bad!r} in the error line" if bad else None


def _no_store(work: Path) -> str | None:
    """Nothing was computed (the refusal came before the first run)."""
    store = work / "data" / "store"
    done = [p for p in store.glob("*/*/manifest.json")] if store.exists() else []
    return f"{len(done)} artifacts computed before refusing" if done else None


def _strict_json(text: str) -> str | None:
    def refuse(name: str) -> object:
        raise ValueError(name)

    try:
        json.loads(text, parse_constant=refuse)
    except ValueError as err:
        return f"stdout is not strict JSON: {str(err)[:80]}"
    return None


def _strict_stdout(_work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    return _strict_json(done.stdout)


# --- symlinked recordings --------------------------------------------------------------


def _link_other_dir(work: Path) -> list[str]:
    target = _rec(work)
    (work / "elsewhere").mkdir()
    (work / "elsewhere" / "linked.mcap").symlink_to(target)
    return ["run", "elsewhere/linked.mcap", "-q"]


def _status_after_linked_run(work: Path) -> list[str]:
    args = _link_other_dir(work)
    _sonarmap(work, *args)
    return ["status", "elsewhere/linked.mcap"]


def _all_hits(_work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    misses = [ln for ln in done.stdout.splitlines() if "miss" in ln]
    return f"status after the run: {misses[:2]}" if misses else None


def _link_relative(work: Path) -> list[str]:
    _rec(work)
    (work / "a" / "b").mkdir(parents=True)
    (work / "a" / "b" / "rel.mcap").symlink_to(Path("../../recs/dive.mcap"))
    return ["status", "a/b/rel.mcap"]


def _link_chain(work: Path) -> list[str]:
    target = _rec(work)
    (work / "one").mkdir()
    (work / "two").mkdir()
    (work / "one" / "l1.mcap").symlink_to(target)
    (work / "two" / "l2.mcap").symlink_to(work / "one" / "l1.mcap")
    return ["status", "two/l2.mcap"]


def _link_dir(work: Path) -> list[str]:
    _rec(work)
    (work / "mounted").symlink_to(work / "recs", target_is_directory=True)
    return ["status", "mounted/dive.mcap"]


def _link_absolute_store_too(work: Path) -> list[str]:
    target = _rec(work)
    (work / "real-store").mkdir()
    (work / "store-link").symlink_to(work / "real-store", target_is_directory=True)
    (work / "x").mkdir()
    (work / "x" / "d.mcap").symlink_to(target)
    return ["status", str(work / "x" / "d.mcap"), "--store", "store-link", "--json"]


def _bag_of_links(work: Path) -> list[str]:
    bag = SHARED_DATA / "bags" / "ros2" / "talker_mcap"
    if not bag.is_dir():
        return ["status", str(work / "no-shared-data")]
    (work / "bag").mkdir()
    for f in bag.iterdir():
        (work / "bag" / f.name).symlink_to(f)
    return ["status", "bag", "--until", "keyframes", "--json"]


def _link_dangling(work: Path) -> list[str]:
    (work / "gone.mcap").symlink_to(work / "never-there.mcap")
    return ["status", "gone.mcap"]


def _link_loop(work: Path) -> list[str]:
    (work / "a.mcap").symlink_to(work / "b.mcap")
    (work / "b.mcap").symlink_to(work / "a.mcap")
    return ["run", "a.mcap"]


# --- long names ------------------------------------------------------------------------


def _long_recording(work: Path) -> list[str]:
    return ["run", "r" * 300 + ".mcap"]


def _name_256(work: Path) -> list[str]:
    return ["status", "n" * 251 + ".mcap"]


def _long_store(work: Path) -> list[str]:
    _rec(work)
    return ["run", "recs/dive.mcap", "--store", "s" * 300]


def _long_sweep_out(work: Path) -> list[str]:
    _rec(work)
    return ["sweep", "recs/dive.mcap", "--out", "o" * 300]


def _over_path_max(work: Path) -> list[str]:
    return ["status", "/".join(["d" * 200] * 30) + "/x.mcap"]


def _huge_path(work: Path) -> list[str]:
    return ["run", "/".join(["p" * 250] * 400)]


def _bounded_line(_work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    line = error_line(done)
    return None if "…" in line and len(line) <= 400 else f"error line not shortened: {line[:80]}"


# --- control characters ------------------------------------------------------------------


def _missing_named(name: str) -> Case:
    def build(work: Path) -> list[str]:
        return ["run", name]

    def check(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
        return _one_clean_line(done)

    return Case("exit codes", f"missing recording named {name!r}", build, check=check)


def _store_in_odd_file(work: Path) -> list[str]:
    _rec(work)
    (work / "odd\rname").write_text("a file, not a folder")
    return ["run", "recs/dive.mcap", "--store", "odd\rname/store"]


def _status_newline_recording(work: Path) -> list[str]:
    _rec(work, "recs/two\nlines.mcap")
    return ["status", "recs/two\nlines.mcap", "--json"]


def _undecodable(work: Path) -> list[str]:
    return ["run", os.fsdecode(b"caf\xe9-\xff.mcap")]


def _one_clean(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    return _one_clean_line(done)


# --- read-only and full outputs --------------------------------------------------------


def _sys_store(work: Path) -> list[str]:
    _rec(work)
    return ["run", "recs/dive.mcap", "--store", "/sys/sonarmap-qa-store"]


def _sys_sweep_out(work: Path) -> list[str]:
    _rec(work)
    return ["sweep", "recs/dive.mcap", "--out", "/sys/sonarmap-qa-sweep"]


def _sys_demo_out(work: Path) -> list[str]:
    return ["demo", "--scene", "tiny", "--duration-s", "5", "--out", "/sys/sonarmap-qa-demo"]


def _sys_study_out(work: Path) -> list[str]:
    return ["study", "--trials", "1", "--out", "/sys/sonarmap-qa-study"]


def _proc_store(work: Path) -> list[str]:
    _rec(work)
    return ["run", "recs/dive.mcap", "--store", "/proc/self/sonarmap-store"]


def _mount(work: Path, name: str, *options: str) -> Path | None:
    """A mount outside the case's folder (unmounted at exit); None when not permitted."""
    point = Path(f"/tmp/sonarmap-qa-{name}-{os.getpid()}")
    point.mkdir(exist_ok=True)
    done = subprocess.run(["mount", *options, str(point)], capture_output=True)
    if done.returncode != 0:
        point.rmdir()
        return None

    def release() -> None:
        subprocess.run(["umount", "-l", str(point)], capture_output=True)
        shutil.rmtree(point, ignore_errors=True)

    atexit.register(release)
    return point


def _ro_bind_store(work: Path) -> list[str]:
    _rec(work)
    (work / "ro").mkdir()
    point = _mount(work, "ro", "--bind", "-o", "ro", str(work / "ro"))
    store = str(point / "store") if point else "/sys/sonarmap-qa-store"
    return ["run", "recs/dive.mcap", "--store", store, "-q"]


def _full_store(work: Path) -> list[str]:
    _rec(work)
    point = _mount(work, "full", "-t", "tmpfs", "-o", "size=4000k", "tmpfs")
    store = str(point / "store") if point else "/dev/full/store"
    return ["run", "recs/dive.mcap", "--store", store, "-q"]


def _full_sweep_out(work: Path) -> list[str]:
    _rec(work)
    point = _mount(work, "fullout", "-t", "tmpfs", "-o", "size=16k", "tmpfs")
    out = str(point / "out") if point else "/dev/full/out"
    return ["sweep", "recs/dive.mcap", "--out", out]


def _store_kept(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    """A full disk under --store is named, and the line says what happened."""
    line = error_line(done)
    return None if "No space left on device" in line or "/dev/full" in line else line[:160]


# --- sweeps ------------------------------------------------------------------------------


def _sweep_missing(work: Path) -> list[str]:
    return ["sweep", "missing.mcap"]


def _sweep_good_and_missing(work: Path) -> list[str]:
    _rec(work)
    return ["sweep", "recs/dive.mcap", "missing.mcap"]


def _sweep_bad_magic(work: Path) -> list[str]:
    _rec(work)
    (work / "corrupt.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 64)
    return ["sweep", "recs/dive.mcap", "corrupt.mcap"]


def _sweep_empty(work: Path) -> list[str]:
    _rec(work)
    (work / "empty.mcap").write_bytes(b"")
    return ["sweep", "recs/dive.mcap", "empty.mcap"]


def _sweep_directory(work: Path) -> list[str]:
    _rec(work)
    (work / "folder").mkdir()
    return ["sweep", "recs/dive.mcap", "folder"]


def _sweep_text(work: Path) -> list[str]:
    (work / "notes.mcap").write_text("not a recording\n")
    return ["sweep", "notes.mcap"]


def _sweep_bad_point(work: Path) -> list[str]:
    _rec(work)
    return ["sweep", "recs/dive.mcap", "--set", "keyframes.spacing_m=2,-1"]


def _sweep_bad_fix(work: Path) -> list[str]:
    _rec(work)
    return ["sweep", "recs/dive.mcap", "--fix", "nosuch.key=1"]


def _sweep_truncated(work: Path) -> list[str]:
    good = _rec(work)
    data = good.read_bytes()
    (work / "cut.mcap").write_bytes(data[: len(data) // 4])
    return ["sweep", "recs/dive.mcap", "cut.mcap", "--out", "out"]


def _tables_written(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    table = work / "out" / "table.md"
    if not table.exists():
        return "no table.md after the failed run"
    failed = [ln for ln in done.stderr.splitlines() if ln.startswith("failed:")]
    if len(failed) != 1 or "cut.mcap" not in failed[0]:
        return f"expected one failed: line naming cut.mcap, got {failed!r}"
    return None


def _refused_first(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    return _no_store(work)


# --- JSON strictness ---------------------------------------------------------------------


def _after_run(*args: str) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        _rec(work)
        _sonarmap(work, "run", "recs/dive.mcap", "-q")
        return [a.replace("REC", "recs/dive.mcap") for a in args]

    return build


def _nan_manifest(work: Path) -> list[str]:
    _rec(work)
    _sonarmap(work, "run", "recs/dive.mcap", "-q", "--until", "fuse")
    manifest = next((work / "data" / "store" / "fuse").glob("*/manifest.json"))
    doc = json.loads(manifest.read_text())
    doc.setdefault("outputs", {}).setdefault("fused", {})["median_cost"] = float("nan")
    doc["outputs"]["fused"]["max_cost"] = float("inf")
    manifest.write_text(json.dumps(doc))
    return ["show", "fuse", "--json"]


# --- workers die with the sweep ------------------------------------------------------


def _children(pid: int) -> set[int]:
    found: set[int] = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            found |= {int(p) for p in (task / "children").read_text().split()}
        except OSError:
            continue
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")


def _orphan_check(work: Path, _done: subprocess.CompletedProcess[str]) -> str | None:
    """kill -9 of a 2-worker sweep's parent alone: both workers gone within 10 s."""
    _rec(work, "recs/b.mcap")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    args = ["sweep", "recs/dive.mcap", "recs/b.mcap", "-j", "2", "--out", "out"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "sonarmap.pipeline", *args],
        cwd=work,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    workers: set[int] = set()
    deadline = time.monotonic() + 60
    while len(workers) < 2 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.2)
        workers = _children(proc.pid)
    if len(workers) < 2:
        proc.kill()
        return f"sweep never had 2 workers ({workers})"
    time.sleep(1.0)  # inside their runs
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    deadline = time.monotonic() + 10
    while any(_alive(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.2)
    left = [p for p in workers if _alive(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    return f"workers {left} outlived the sweep" if left else None


def _prepare_orphans(work: Path) -> list[str]:
    _rec(work)
    return ["sweep", "--help"]


CASES = [
    # symlinked recordings
    Case("exit codes", "run of a recording symlinked from another folder", _link_other_dir,
         expect_exit=(0,), max_seconds=RUN_S),
    Case("exit codes", "status after a run through a symlink: all hits", _status_after_linked_run,
         expect_exit=(0,), check=_all_hits),
    Case("exit codes", "status of a relative symlink two folders down", _link_relative,
         expect_exit=(0,)),
    Case("exit codes", "status through a chain of two symlinks", _link_chain, expect_exit=(0,)),
    Case("exit codes", "status through a symlinked folder", _link_dir, expect_exit=(0,)),
    Case("exit codes", "status with a symlinked store and recording", _link_absolute_store_too,
         expect_exit=(0,), check=_strict_stdout),
    Case("exit codes", "status of a bag folder made of symlinks", _bag_of_links,
         expect_exit=(0,), check=_strict_stdout),
    Case("exit codes", "dangling symlink", _link_dangling, check=names("gone.mcap")),
    Case("exit codes", "symlink loop", _link_loop, check=names("a.mcap")),
    # long names
    Case("exit codes", "recording name of 300 characters", _long_recording,
         check=names("File name too long")),
    Case("exit codes", "recording name of 256 characters", _name_256,
         check=names("File name too long")),
    Case("exit codes", "--store with a 300-character component", _long_store,
         check=names("File name too long")),
    Case("exit codes", "sweep --out with a 300-character component", _long_sweep_out,
         check=names("File name too long")),
    Case("exit codes", "path longer than PATH_MAX", _over_path_max, check=_bounded_line),
    Case("resources", "a 100 KB path: error line bounded", _huge_path, check=_bounded_line),
    # control characters
    _missing_named("new\nline.mcap"),
    _missing_named("carriage\rreturn.mcap"),
    _missing_named("esc\x1b[2J\x1b[31mred.mcap"),
    _missing_named("tab\tand\x7fdel.mcap"),
    _missing_named("line\u2028separator.mcap"),
    _missing_named("bell\x07.mcap"),
    Case("exit codes", "--store inside a file whose name has a carriage return",
         _store_in_odd_file, check=_one_clean),
    Case("exit codes", "status of an existing recording with a newline in its name",
         _status_newline_recording, expect_exit=(0,), check=_strict_stdout),
    Case("exit codes", "recording name with undecodable bytes", _undecodable, check=_one_clean),
    # read-only and full outputs
    Case("exit codes", "--store under read-only /sys", _sys_store,
         check=names("/sys/sonarmap-qa-store")),
    Case("exit codes", "--store under /proc", _proc_store, check=names("/proc/self")),
    Case("exit codes", "sweep --out under read-only /sys", _sys_sweep_out,
         check=lambda w, d: names("/sys/sonarmap-qa-sweep")(w, d) or _no_store(w)),
    Case("exit codes", "demo --out under read-only /sys", _sys_demo_out,
         check=names("/sys/sonarmap-qa-demo")),
    Case("exit codes", "study --out under read-only /sys", _sys_study_out,
         check=names("/sys/sonarmap-qa-study")),
    Case("exit codes", "--store on a read-only bind mount", _ro_bind_store,
         check=names("store")),
    Case("exit codes", "--store on a full 4 MB tmpfs", _full_store, check=_store_kept,
         max_seconds=RUN_S),
    Case("exit codes", "sweep --out on a full 16 KB tmpfs", _full_sweep_out,
         max_seconds=RUN_S),
    # sweeps
    Case("exit codes", "sweep of a missing recording", _sweep_missing,
         check=names("missing.mcap")),
    Case("exit codes", "sweep of a good and a missing recording", _sweep_good_and_missing,
         check=lambda w, d: names("missing.mcap")(w, d) or _no_store(w)),
    Case("exit codes", "sweep with a corrupt MCAP", _sweep_bad_magic,
         check=lambda w, d: names("corrupt.mcap")(w, d) or _no_store(w)),
    Case("exit codes", "sweep with an empty file", _sweep_empty,
         check=lambda w, d: names("empty.mcap")(w, d) or _no_store(w)),
    Case("exit codes", "sweep with a folder that is not a bag", _sweep_directory,
         check=lambda w, d: names("folder")(w, d) or _no_store(w)),
    Case("exit codes", "sweep of a text file", _sweep_text, check=names("notes.mcap")),
    Case("exit codes", "sweep with one bad swept value", _sweep_bad_point,
         check=_refused_first),
    Case("exit codes", "sweep with a bad --fix key", _sweep_bad_fix, check=_refused_first),
    Case("exit codes", "sweep with a truncated recording beside a good one", _sweep_truncated,
         check=_tables_written, max_seconds=RUN_S),
    # JSON
    Case("exit codes", "show fuse --json after a run", _after_run("show", "fuse", "--json"),
         expect_exit=(0,), check=_strict_stdout),
    Case("exit codes", "show evaluate --json after a run",
         _after_run("show", "evaluate", "--json"), expect_exit=(0,), check=_strict_stdout),
    Case("exit codes", "show train --json after a run", _after_run("show", "train", "--json"),
         expect_exit=(0,), check=_strict_stdout),
    Case("exit codes", "ls --json after a run", _after_run("ls", "--json"), expect_exit=(0,),
         check=_strict_stdout),
    Case("exit codes", "status --json after a run", _after_run("status", "REC", "--json"),
         expect_exit=(0,), check=_strict_stdout),
    Case("exit codes", "run --json, cached", _after_run("run", "REC", "--json", "-q"),
         expect_exit=(0,), check=_strict_stdout),
    Case("exit codes", "sweep --json", _after_run("sweep", "REC", "--json", "--out", "o"),
         expect_exit=(0,), check=_strict_stdout, max_seconds=RUN_S),
    Case("exit codes", "show --json of a manifest holding NaN and inf", _nan_manifest,
         expect_exit=(0,), check=_strict_stdout),
    # resources
    Case("resources", "kill -9 of a 2-worker sweep's parent: workers die", _prepare_orphans,
         expect_exit=(0,), check=_orphan_check),
]  # fmt: skip
