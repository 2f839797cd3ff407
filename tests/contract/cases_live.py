"""Live and interrupted runs against `gc`, disk faults during `run`, refused model
files, and runs that would end in an empty map.

Cases on the toy graph (`tests/toy_stages.py`, via $SONARMAP_GRAPH) hold a run inside
its second stage with a gate file, so `gc` meets it mid-run deterministically; cases on
the real pipeline use the small simulated recording of `tests.contract.fixtures`. Disk
-full cases mount a small tmpfs (root only; they fail where mounting is not allowed).
"""

from __future__ import annotations

import atexit
import hashlib
import io
import json
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from tests.contract.case import Case, names
from tests.fixtures import ROOT, small_recording
from tests.fixtures.signals import default_sigint

STORE = "data/store"
TOY_ENV = {"SONARMAP_GRAPH": "tests.toy_stages:GRAPH", "PYTHONPATH": str(ROOT)}
_BACKGROUND: dict[str, subprocess.Popen[bytes]] = {}


def _wait_for(path: Path, text: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text():
            return
        time.sleep(0.02)
    raise RuntimeError(f"{text!r} never appeared in {path}")


def _toy_command(*extra: str) -> list[str]:
    """`sonarmap run` of the toy recording into the case's store."""
    return [sys.executable, "-m", "sonarmap.pipeline", "run", "raw.bin", "--store", STORE, "-q",
            *extra]  # fmt: skip


def _toy_run(work: Path, *extra: str, gate: bool = True) -> subprocess.Popen[bytes]:
    """A toy run in the background, held in its `double` stage until `work/gate` exists."""
    data = work / "raw.bin"
    data.write_bytes(bytes(range(256)) * 4)
    env = {**os.environ, **TOY_ENV, "TOY_CALL_LOG": str(work / "calls.log")}
    if gate:
        env["TOY_GATE"] = str(work / "gate")
    return _spawn(_toy_command(*extra), work, env)


def _spawn(cmd: list[str], work: Path, env: dict[str, str]) -> subprocess.Popen[bytes]:
    """`cmd` in the background in `work`, Ctrl-C-able, its stderr kept; killed at exit."""
    proc = subprocess.Popen(
        cmd,
        cwd=work,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        preexec_fn=default_sigint,
    )
    atexit.register(proc.kill)  # a case that fails before its check leaves no run behind
    return proc


def _artifacts(work: Path) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for manifest in sorted((work / STORE).glob("*/*/manifest.json")):
        out.setdefault(manifest.parent.parent.name, []).append(manifest.parent.name)
    return out


def _orphan(work: Path) -> None:
    """An unreferenced artifact (another config's run, its record gone): gc must take it."""
    proc = _toy_run(work, "--set", "source.scale=3", "--until", "source", gate=False)
    proc.wait(timeout=60)
    for record in (work / STORE / "runs").glob("*.json"):
        record.unlink()
    (work / "orphan").write_text(json.dumps(_artifacts(work)["source"]))


def _orphan_gone(work: Path) -> str | None:
    orphan = json.loads((work / "orphan").read_text())
    left = set(orphan) & set(_artifacts(work).get("source", []))
    return f"the unreferenced artifact survived gc: {sorted(left)}" if left else None


# -- data loss: gc during a live run ----------------------------------------------------------


def _gc_live(*gc_args: str) -> Any:
    def build(work: Path) -> list[str]:
        _orphan(work)
        _BACKGROUND[str(work)] = _toy_run(work)
        _wait_for(work / "calls.log", "double")
        (work / "before.json").write_text(json.dumps(_artifacts(work)))
        return ["gc", "--store", STORE, *gc_args]

    return build


def _live_run_finishes(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    before = json.loads((work / "before.json").read_text())
    run_source = [k for k in before["source"] if k not in json.loads((work / "orphan").read_text())]
    if not set(run_source) <= set(_artifacts(work).get("source", [])):
        return "gc removed the live run's committed `source`"
    (work / "gate").touch()
    proc = _BACKGROUND.pop(str(work))
    _, err = proc.communicate(timeout=60)
    if proc.returncode != 0:
        return f"the live run failed after gc: {err.decode().strip()[-200:]}"
    if set(_artifacts(work)) != {"source", "double", "summary", "count"}:
        return f"artifacts after the run: {sorted(_artifacts(work))}"
    if "dry-run" not in " ".join(done.args) and (why := _orphan_gone(work)):
        return why
    if "in progress" not in done.stdout and "--json" not in done.args:
        return "gc did not say a run was in progress"
    return None


def _gc_live_twice(work: Path) -> list[str]:
    """Two gcs back to back against the same live run."""
    args = _gc_live()(work)
    first = subprocess.run(
        [sys.executable, "-m", "sonarmap.pipeline", *args], cwd=work, env={**os.environ, **TOY_ENV}
    )
    if first.returncode != 0:
        raise RuntimeError("the first gc failed")
    return args


# -- data loss: gc after an interrupted run ---------------------------------------------------


def _interrupted(sig: int) -> Any:
    def build(work: Path) -> list[str]:
        proc = _toy_run(work)
        _wait_for(work / "calls.log", "double")
        proc.send_signal(sig)
        proc.communicate(timeout=60)
        return ["gc", "--store", STORE]

    return build


def _failed_later_stage(work: Path) -> list[str]:
    proc = _toy_run(work, "--set", "summary.fail=true", gate=False)
    proc.communicate(timeout=60)
    return ["gc", "--store", STORE]


def _finished_work_kept(*stages: str) -> Any:
    def check(work: Path, _done: subprocess.CompletedProcess[str]) -> str | None:
        have = _artifacts(work)
        missing = [s for s in stages if s not in have]
        if missing:
            return f"gc removed the interrupted run's finished {missing}"
        if list((work / STORE / ".leases").glob("*.json")):
            return "a dead run's lease was not removed"
        if list((work / STORE / ".tmp").iterdir()):
            return "the killed commit's temporary directory is left"
        rerun = subprocess.run(
            _toy_command("--json"),
            cwd=work,
            env={**os.environ, **TOY_ENV},
            capture_output=True,
            text=True,
        )
        if rerun.returncode != 0:
            return f"rerun failed: {rerun.stderr.strip()[-200:]}"
        statuses = {s["stage"]: s["status"] for s in json.loads(rerun.stdout)["stages"]}
        recomputed = [s for s in stages if statuses.get(s) != "hit"]
        return f"rerun recomputed {recomputed}" if recomputed else None

    return check


# -- data loss: the real pipeline, gc while it runs -------------------------------------------


def _real_gc_mid_run(work: Path) -> list[str]:
    small_recording(work / "rec.mcap")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-m", "sonarmap.pipeline", "run", "rec.mcap", "--store", STORE, "-q",
           "--until", "slam"]  # fmt: skip
    proc = _spawn(cmd, work, env)
    _BACKGROUND[str(work)] = proc
    deadline = time.monotonic() + 120
    while not list((work / STORE / "features").glob("*/manifest.json")):
        if time.monotonic() > deadline or _BACKGROUND[str(work)].poll() is not None:
            raise RuntimeError("the run never committed features")
        time.sleep(0.05)
    return ["gc", "--store", STORE]


def _real_run_survives(work: Path, _done: subprocess.CompletedProcess[str]) -> str | None:
    proc = _BACKGROUND.pop(str(work))
    _, err = proc.communicate(timeout=300)
    if proc.returncode != 0:
        return f"the run failed after gc: {err.decode().strip()[-200:]}"
    have = set(_artifacts(work))
    want = {"keyframes", "features", "fuse", "classify", "slam", "train"}
    return f"missing after the run: {sorted(want - have)}" if want - have else None


# -- exit codes: disk faults during run -------------------------------------------------------


def _tmpfs(work: Path, size: str) -> Path:
    mount = Path(f"/tmp/sonarmap-qa-tmpfs-{os.getpid()}")
    mount.mkdir(exist_ok=True)
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mount)], check=True)
    atexit.register(subprocess.run, ["umount", "-l", str(mount)])
    return mount


def _disk_full(size: str, real: bool) -> Any:
    def build(work: Path) -> list[str]:
        mount = _tmpfs(work, size)
        (work / "store-path").write_text(str(mount / "store"))
        if real:
            small_recording(work / "rec.mcap")
            return ["run", "rec.mcap", "--store", str(mount / "store"), "-q"]
        # `source` (~100 KB of Parquet) fits, `double` (a 512 KB blob more) does not.
        (work / "raw.bin").write_bytes(os.urandom(65536))
        return ["run", "raw.bin", "--store", str(mount / "store"), "-q",
                "--set", "source.n_rows=65536"]  # fmt: skip

    return build


def _disk_full_left_it_clean(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    store = Path((work / "store-path").read_text())
    if "No space left" not in done.stderr:
        return "the error does not say the disk is full"
    if list((store / ".tmp").glob("*")):
        return "a partial commit is left under .tmp"
    before = sorted(store.glob("*/*/manifest.json"))
    for manifest in before:
        doc = json.loads(manifest.read_text())
        for rel, info in doc["files"].items():
            digest = hashlib.sha256((manifest.parent / rel).read_bytes()).hexdigest()
            if digest != info["sha256"]:
                return f"{manifest.parent}: '{rel}' does not match its manifest"
    gc = subprocess.run([sys.executable, "-m", "sonarmap.pipeline", "gc", "--store", str(store)],
                        cwd=work, capture_output=True, text=True)  # fmt: skip
    after = sorted(store.glob("*/*/manifest.json"))
    if gc.returncode != 0 or after != before:
        return f"gc after the full disk removed committed work ({len(before)} -> {len(after)})"
    return None


def _store_under(path: str) -> Any:
    def build(work: Path) -> list[str]:
        (work / "raw.bin").write_bytes(bytes(range(256)) * 4)
        (work / "a-file").write_text("not a directory")
        return ["run", "raw.bin", "--store", path.replace("WORK", str(work)), "-q"]

    return build


def _read_only_tmpfs(work: Path) -> list[str]:
    mount = _tmpfs(work, "1m")
    subprocess.run(["mount", "-o", "remount,ro", str(mount)], check=True)
    (work / "raw.bin").write_bytes(bytes(range(256)) * 4)
    return ["run", "raw.bin", "--store", str(mount / "store"), "-q"]


# -- trust: a model.pt that is not a weights-only state dict -----------------------------------


class _Evil:
    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, ...]:
        return (os.system, (f"touch {self.marker}",))


def _bad_model(kind: str, marker: Path) -> bytes:
    import torch

    buf = io.BytesIO()
    if kind == "malicious zip":
        torch.save({"state_dict": _Evil(str(marker)), "class_names": ["x"], "config": {}}, buf)
    elif kind == "malicious legacy pickle":
        return pickle.dumps(_Evil(str(marker)), protocol=2)
    elif kind == "other state dict":
        torch.save({"weights": torch.zeros(3)}, buf)
    elif kind == "junk zip":
        return b"PK\x03\x04" + os.urandom(4096)
    elif kind == "truncated model":
        return b""  # replaced below by the real model's first half
    return buf.getvalue()


def _planted_model(kind: str) -> Any:
    """A store whose `train` artifact's model.pt was replaced, manifest updated to match
    (what a careless colleague's push, or a hand edit, leaves)."""

    def build(work: Path) -> list[str]:
        small_recording(work / "rec.mcap")
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        cmd = [sys.executable, "-m", "sonarmap.pipeline", "run", "rec.mcap", "--store", STORE, "-q",
               "--until", "classify"]  # fmt: skip
        subprocess.run(cmd, cwd=work, env=env, check=True, capture_output=True)
        (train,) = (work / STORE / "train").iterdir()
        model = train / "model.pt"
        data = _bad_model(kind, work / "pwned")
        if kind == "truncated model":
            data = model.read_bytes()[: model.stat().st_size // 2]
        model.write_bytes(data)
        manifest = json.loads((train / "manifest.json").read_text())
        manifest["files"]["model.pt"] = {"sha256": hashlib.sha256(data).hexdigest(),
                                         "size": len(data)}  # fmt: skip
        (train / "manifest.json").write_text(json.dumps(manifest))
        (work / "train-key").write_text(train.name)
        return ["run", "rec.mcap", "--store", STORE, "-q", "--until", "classify",
                "--force", "classify"]  # fmt: skip

    return build


def _model_refused(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    if (work / "pwned").exists():
        return "the pickle's code ran"
    key = (work / "train-key").read_text()
    line = next((ln for ln in done.stderr.splitlines() if ln.startswith("error:")), "")
    if f"train/{key}/model.pt" not in line or "weights-only state dict" not in line:
        return f"the error does not name the model file: {line[:160]}"
    if "weights_only=False" in done.stderr:
        return "the message suggests weights_only=False"
    return None


# -- empty maps --------------------------------------------------------------------------------


def _toy_empty(*sets: str) -> Any:
    def build(work: Path) -> list[str]:
        (work / "raw.bin").write_bytes(bytes(range(256)) * 4)
        args = ["run", "raw.bin", "--store", STORE, "--json"]
        for item in sets:
            args += ["--set", item]
        return args

    return build


STARVED = ["--set", "features.intensity_floor=250"]
"""A floor pinned near saturation: the small recording's features then never fuse (the
calibrated front end fuses a few points on it, the old fixed one none; these cases are
about what a run says when fusion collapses)."""


def _real_nav_jump(work: Path) -> list[str]:
    """The small recording, starved: 0 fused points from hundreds of features."""
    small_recording(work / "rec.mcap")
    return ["run", "rec.mcap", "--store", STORE, "-q", *STARVED]


def _real_until(stage: str, *extra: str) -> Any:
    def build(work: Path) -> list[str]:
        small_recording(work / "rec.mcap")
        return ["run", "rec.mcap", "--store", STORE, "-q", "--json", "--until", stage, *extra]

    return build


def _rewrite(src: Path, dst: Path, sonar: Any = None, nav: Any = None) -> None:
    """Copy a recording, passing each sonar image (`sonar(msg, index, t)`) and each
    dead-reckoning message (`nav(msg, index, count)`) through a change."""
    import dataclasses as dc

    from mcap.reader import make_reader

    from sonarmap.pipeline.formats.rosmsg import Ros2McapWriter, ros2_typestore

    store = ros2_typestore()
    with src.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        nav_count = sum(
            n
            for c, n in summary.statistics.channel_message_counts.items()
            if summary.channels[c].topic == "/odometry/dead_reckoning"
        )
        seen: dict[str, int] = {}
        with dst.open("wb") as out, Ros2McapWriter(out) as writer:
            for schema, channel, message in reader.iter_messages(log_time_order=True):
                topic, data, t = channel.topic, bytes(message.data), message.log_time
                i = seen[topic] = seen.get(topic, -1) + 1
                if sonar is not None and topic in ("/sonar/horizontal", "/sonar/vertical"):
                    msg, t = sonar(store.deserialize_cdr(data, schema.name), i, t, dc)
                    data = bytes(store.serialize_cdr(msg, schema.name))
                elif nav is not None and topic == "/odometry/dead_reckoning":
                    msg = nav(store.deserialize_cdr(data, schema.name), i, nav_count, dc)
                    data = bytes(store.serialize_cdr(msg, schema.name))
                writer.write_raw(topic, schema.name, data, t)
            for attachment in reader.iter_attachments():
                writer.add_attachment(attachment.name, attachment.data, attachment.media_type)
            for metadata in reader.iter_metadata():
                writer.add_metadata(metadata.name, dict(metadata.metadata))


def _image(msg: Any, dc: Any, ranges: Any, directions: Any, data: Any) -> Any:
    image = dc.replace(msg.image, beam_count=len(directions), data=data)
    return dc.replace(msg, ranges=ranges, beam_directions=directions, image=image)


def _zero_beams(m: Any, i: int, t: int, dc: Any) -> Any:
    import numpy as np

    return _image(m, dc, m.ranges, [], np.zeros(0, np.uint8)), t


def _one_pixel(m: Any, i: int, t: int, dc: Any) -> Any:
    return _image(m, dc, m.ranges[:1], m.beam_directions[:1], m.image.data[:1]), t


def _ranges(scale: float, reverse: bool = False) -> Any:
    def change(m: Any, i: int, t: int, dc: Any) -> Any:
        import numpy as np

        ranges = (m.ranges[::-1] if reverse else m.ranges) * np.float32(scale)
        return dc.replace(m, ranges=ranges.astype(np.float32)), t

    return change


def _one_timestamp(m: Any, i: int, t: int, dc: Any) -> Any:
    stamp = dc.replace(m.header.stamp, sec=1_700_000_000, nanosec=0)
    return dc.replace(m, header=dc.replace(m.header, stamp=stamp)), 1_700_000_000 * 10**9


def _infinite_directions(m: Any, i: int, t: int, dc: Any) -> Any:
    directions = [dc.replace(d, x=float("inf")) for d in m.beam_directions]
    return dc.replace(m, beam_directions=directions), t


HOSTILE_SONAR: dict[str, Any] = {
    "all pings with zero beams": _zero_beams,
    "1x1 images": _one_pixel,
    "negative ranges": _ranges(-1.0),
    "descending ranges": _ranges(1.0, reverse=True),
    "ranges x1e30": _ranges(1e30),
    "infinite beam directions": _infinite_directions,
    "all sonar messages at one timestamp": _one_timestamp,
}


def _nav_jump(m: Any, i: int, n: int, dc: Any) -> Any:
    """Dead reckoning 1 km off for the second half of the mission."""
    if i < n // 2:
        return m
    p = m.pose.pose.position
    pose = dc.replace(m.pose.pose, position=dc.replace(p, x=p.x + 1000.0))
    return dc.replace(m, pose=dc.replace(m.pose, pose=pose))


def _hostile(variant: str) -> Any:
    def build(work: Path) -> list[str]:
        clean = small_recording(work / "clean.mcap", seed=2, duration_s=45.0)
        if variant == "1 km navigation jump":
            _rewrite(clean, work / "rec.mcap", nav=_nav_jump)
        else:
            _rewrite(clean, work / "rec.mcap", sonar=HOSTILE_SONAR[variant])
        return ["run", "rec.mcap", "--store", STORE, "-q", "--json"]

    return build


def _hostile_clean(work: Path) -> list[str]:
    small_recording(work / "rec.mcap", seed=2, duration_s=45.0)
    return ["run", "rec.mcap", "--store", STORE, "-q", "--json"]


def _not_silent(_work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    """Exit 2 (judged by the campaign) or exit 0 with at least one warning."""
    if done.returncode == 0 and "warning:" not in done.stderr:
        summary = json.loads(done.stdout).get("summary", {})
        return f"exit 0 without a warning (points {summary.get('points')})"
    return None


def _warns(*needles: str) -> Any:
    def check(_work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
        lines = [ln for ln in done.stderr.splitlines() if ln.startswith(("warning:", "error:"))]
        text = "\n".join(lines)
        missing = [n for n in needles if n not in text]
        if missing:
            return f"no line says {missing}: {text[:200]}"
        if done.returncode == 0 and "--json" in done.args:
            warnings = json.loads(done.stdout).get("warnings", [])
            if not any(needles[0] in w for w in warnings):
                return "`run --json` lists no such warning"
        return None

    return check


def _silent(_work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    if "warning:" in done.stderr:
        return f"a warning on a normal run: {done.stderr.strip()[:200]}"
    if "--json" in done.args and json.loads(done.stdout).get("warnings"):
        return "`run --json` lists warnings on a normal run"
    return None


_TOY = TOY_ENV
_REAL = {"max_seconds": 120.0}
_OK = (0,)

CASES = [
    # data loss: gc meets a live run, or the leftovers of an interrupted one
    Case(
        "data loss", "gc during a live run", _gc_live(), expect_exit=_OK, check=_live_run_finishes
    ),
    Case(
        "data loss",
        "gc --json during a live run",
        _gc_live("--json"),
        expect_exit=_OK,
        check=_live_run_finishes,
    ),
    Case(
        "data loss",
        "gc --dry-run during a live run",
        _gc_live("--dry-run"),
        expect_exit=_OK,
        check=_live_run_finishes,
    ),
    Case(
        "data loss",
        "gc --broken during a live run",
        _gc_live("--broken"),
        expect_exit=_OK,
        check=_live_run_finishes,
    ),
    Case(
        "data loss",
        "two gcs during a live run",
        _gc_live_twice,
        expect_exit=_OK,
        check=_live_run_finishes,
    ),
    Case(
        "data loss",
        "gc after SIGINT mid-run",
        _interrupted(signal.SIGINT),
        expect_exit=_OK,
        check=_finished_work_kept("source"),
    ),
    Case(
        "data loss",
        "gc after SIGTERM mid-run",
        _interrupted(signal.SIGTERM),
        expect_exit=_OK,
        check=_finished_work_kept("source"),
    ),
    Case(
        "data loss",
        "gc after kill -9 mid-run",
        _interrupted(signal.SIGKILL),
        expect_exit=_OK,
        check=_finished_work_kept("source"),
    ),
    Case(
        "data loss",
        "gc after a failing later stage",
        _failed_later_stage,
        expect_exit=_OK,
        check=_finished_work_kept("source", "double"),
    ),
    Case(
        "data loss",
        "gc during a real run (after features)",
        _real_gc_mid_run,
        expect_exit=_OK,
        check=_real_run_survives,
        **_REAL,
    ),
    Case(
        "data loss",
        "disk full at the first commit",
        _disk_full("256k", real=True),
        check=_disk_full_left_it_clean,
        **_REAL,
    ),
    Case(
        "data loss",
        "disk full mid-run (real)",
        _disk_full("3900k", real=True),
        check=_disk_full_left_it_clean,
        **_REAL,
    ),
    Case(
        "data loss",
        "disk full mid-run (toy)",
        _disk_full("384k", real=False),
        check=_disk_full_left_it_clean,
        env=_TOY,
    ),
    # exit codes: the store cannot be written
    Case(
        "exit codes",
        "store name over 255 characters",
        _store_under("WORK/" + "s" * 300),
        check=names("File name too long", "s…s"),
        env=_TOY,
    ),
    Case(
        "exit codes",
        "store under a regular file",
        _store_under("WORK/a-file/store"),
        check=names("a-file", "Not a directory"),
        env=_TOY,
    ),
    Case(
        "exit codes",
        "store on a read-only filesystem",
        _read_only_tmpfs,
        check=names("Read-only file system"),
        env=_TOY,
    ),
    Case(
        "exit codes",
        "store in /proc",
        _store_under("/proc/sonarmap-store"),
        check=names("/proc/sonarmap-store"),
        env=_TOY,
    ),
    Case(
        "exit codes",
        "store path with a newline",
        _store_under("WORK/new\nline/" + "x" * 300),
        check=names("new\\nline"),
        env=_TOY,
    ),
    # trust: model.pt is not a weights-only state dict
    *[
        Case("trust", f"model.pt: {kind}", _planted_model(kind), check=_model_refused, **_REAL)
        for kind in (
            "malicious zip",
            "malicious legacy pickle",
            "other state dict",
            "junk zip",
            "truncated model",
        )
    ],
    # empty maps: warned about, and no map at all is exit 2
    Case(
        "empty maps", "toy run is silent", _toy_empty(), expect_exit=(0,), check=_silent, env=_TOY
    ),
    Case(
        "empty maps",
        "real small recording: no fused points, no map",
        _real_nav_jump,
        check=_warns("fuse: 0 fused points", "no map"),
        **_REAL,
    ),
    Case(
        "empty maps",
        "real run until fuse: fused collapse warned",
        _real_until("fuse", *STARVED),
        expect_exit=(0,),
        check=_warns("fuse: 0 fused points"),
        **_REAL,
    ),
    *[
        Case(
            "empty maps", variant, _hostile(variant), expect_exit=(0, 2), check=_not_silent, **_REAL
        )
        for variant in (*HOSTILE_SONAR, "1 km navigation jump")
    ],
    Case(
        "empty maps",
        "clean 45 s recording is silent",
        _hostile_clean,
        expect_exit=(0,),
        check=_silent,
        **_REAL,
    ),
    Case(
        "empty maps",
        "real run until features is silent",
        _real_until("features"),
        expect_exit=(0,),
        check=_silent,
        **_REAL,
    ),
]
