"""The Foxglove outputs and the live view (issue 40): `sonarmap view` and `run --live`
refused cleanly (bad recording, no finished run, bad or busy port, a tampered store),
and the map MCAP / PLY of a finished run readable by standard readers.

`view` and a successful `run --live` serve until Ctrl-C, so only their refusals are
cases here; serving is tested in tests/test_live_view.py.
"""

from __future__ import annotations

import io
import os
import shutil
import socket
import subprocess
from pathlib import Path

from tests.contract.case import Case, names
from tests.fixtures import CACHE, cached_run, small_recording

RUN = CACHE / "foxglove-run"
_HELD: list[socket.socket] = []
"""Sockets a case keeps bound while its command runs (a busy port)."""


def _cached_run() -> Path:
    """A work dir after `sonarmap run rec.mcap` (made once per code version)."""
    return cached_run(RUN.name)


def _fresh_run(work: Path) -> None:
    run = _cached_run()
    shutil.copyfile(run / "rec.mcap", work / "rec.mcap")
    shutil.copytree(run / "data", work / "data")


def _artifact(work: Path, stage: str) -> Path:
    root = work / "data" / "store" / stage
    return next(p for p in root.iterdir() if (p / "manifest.json").is_file())


def _busy_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen(1)
    _HELD.append(s)
    return int(s.getsockname()[1])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _port_released(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    port = int((work / "port").read_text())
    try:
        with socket.socket() as s:
            s.bind(("127.0.0.1", port))
    except OSError as err:
        return f"port {port} still taken after the run ended: {err}"
    return None


def _no_serving_line(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    if "serving" in done.stderr:
        return "kept serving after a failed run"
    return None


# --- builders -----------------------------------------------------------------------


def _view_missing(work: Path) -> list[str]:
    return ["view", "nope.mcap", "--port", "0"]


def _view_empty(work: Path) -> list[str]:
    (work / "empty.mcap").write_bytes(b"")
    return ["view", "empty.mcap", "--port", "0"]


def _view_garbage(work: Path) -> list[str]:
    (work / "junk.mcap").write_bytes(os.urandom(4096))
    return ["view", "junk.mcap", "--port", "0"]


def _view_no_run(work: Path) -> list[str]:
    small_recording(work / "rec.mcap", seed=2, duration_s=45.0)
    return ["view", "rec.mcap", "--port", "0"]


def _view_other_config(work: Path) -> list[str]:
    _fresh_run(work)
    # a config whose first stage differs: nothing of this run is finished
    return ["view", "rec.mcap", "--set", "keyframes.spacing_m=3.7", "--port", "0"]


def _view_port_range(work: Path) -> list[str]:
    (work / "rec.mcap").write_bytes(b"")
    return ["view", "rec.mcap", "--port", "70000"]


def _view_port_busy(work: Path) -> list[str]:
    _fresh_run(work)
    return ["view", "rec.mcap", "--port", str(_busy_port())]


def _view_corrupt(work: Path, stage: str, name: str) -> list[str]:
    _fresh_run(work)
    path = _artifact(work, stage) / name
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    return ["view", "rec.mcap", "--port", "0"]


def _view_missing_file(work: Path) -> list[str]:
    _fresh_run(work)
    (_artifact(work, "keyframes") / "keyframes.mcap").unlink()
    return ["view", "rec.mcap", "--port", "0"]


def _view_bad_set(work: Path) -> list[str]:
    _fresh_run(work)
    return ["view", "rec.mcap", "--set", "keyframes.spacing_m=-1", "--port", "0"]


def _view_store_is_file(work: Path) -> list[str]:
    _fresh_run(work)
    (work / "store.txt").write_text("not a store")
    return ["view", "rec.mcap", "--store", "store.txt", "--port", "0"]


def _run_live_port_range(work: Path) -> list[str]:
    small_recording(work / "rec.mcap", seed=2, duration_s=45.0)
    return ["run", "rec.mcap", "--live", "--live-port", "-1"]


def _run_live_port_busy(work: Path) -> list[str]:
    small_recording(work / "rec.mcap", seed=2, duration_s=45.0)
    return ["run", "rec.mcap", "--live", "--live-port", str(_busy_port())]


def _run_live_bad_recording(work: Path, json_: bool) -> list[str]:
    (work / "junk.mcap").write_bytes(b"\x89MCAP0\r\n" + os.urandom(2000))
    port = _free_port()
    (work / "port").write_text(str(port))
    return ["run", "junk.mcap", "--live", "--live-port", str(port), *(["--json"] if json_ else [])]


def _run_live_missing(work: Path) -> list[str]:
    port = _free_port()
    (work / "port").write_text(str(port))
    return ["run", "missing.mcap", "--live", "--live-port", str(port), "-q"]


# --- readers of a finished run's outputs (a case is a command, so `sonarmap show`) ------


def _mcap_valid(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    from mcap.reader import make_reader

    data = (_artifact(work, "evaluate") / "map.mcap").read_bytes()
    reader = make_reader(io.BytesIO(data), validate_crcs=True)
    summary = reader.get_summary()
    if summary is None or summary.statistics is None:
        return "map.mcap has no summary"
    n = sum(1 for _ in reader.iter_messages())
    schemas = {s.name for s in summary.schemas.values()}
    if n != summary.statistics.message_count or not all(s.startswith("foxglove.") for s in schemas):
        return f"{n} messages vs {summary.statistics.message_count}; schemas {sorted(schemas)}"
    return None


def _ply_readable(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    from plyfile import PlyData

    ply = PlyData.read(str(_artifact(work, "voxelize") / "map_semantic.ply"))
    names = [p.name for p in ply["vertex"].properties]
    want = ["class_id", "source", "keyframe_id"]
    return None if names[-3:] == want else f"vertex properties {names}"


def _show(stage: str):  # type: ignore[no-untyped-def]
    def build(work: Path) -> list[str]:
        _fresh_run(work)
        return ["show", stage, "--verify"]

    return build


CASES: list[Case] = [
    Case("exit codes", "view: recording missing", _view_missing, check=names("nope.mcap")),
    Case("exit codes", "view: empty recording", _view_empty, check=names("empty.mcap")),
    Case("exit codes", "view: random bytes", _view_garbage, check=names("junk.mcap")),
    Case("exit codes", "view: no finished run", _view_no_run, check=names("rec.mcap")),
    Case("exit codes", "view: other config", _view_other_config, check=names("rec.mcap")),
    Case("exit codes", "view: --port 70000", _view_port_range, check=names("port")),
    Case("exit codes", "view: port busy", _view_port_busy, check=names("cannot listen")),
    Case("exit codes", "view: --set out of bounds", _view_bad_set, check=names("spacing_m")),
    Case("exit codes", "view: --store is a file", _view_store_is_file, check=names("store.txt")),
    Case("exit codes", "run --live-port -1", _run_live_port_range, check=names("live-port")),
    Case("exit codes", "run --live: port busy", _run_live_port_busy, check=names("cannot listen")),
    Case(
        "exit codes",
        "run --live: bad recording frees its port",
        lambda w: _run_live_bad_recording(w, False),
        check=_port_released,
    ),
    Case(
        "exit codes",
        "run --live --json: bad recording",
        lambda w: _run_live_bad_recording(w, True),
        check=_no_serving_line,
    ),
    Case(
        "exit codes",
        "run --live: missing recording",
        _run_live_missing,
        check=_port_released,
    ),
    Case(
        "trust",
        "view: flipped byte in map.parquet",
        lambda w: _view_corrupt(w, "voxelize", "map.parquet"),
        check=names("voxelize"),
    ),
    Case(
        "trust",
        "view: flipped byte in map.mcap",
        lambda w: _view_corrupt(w, "evaluate", "map.mcap"),
        check=names("evaluate"),
    ),
    Case(
        "trust",
        "view: flipped byte in keyframes.mcap",
        lambda w: _view_corrupt(w, "keyframes", "keyframes.mcap"),
        check=names("keyframes"),
    ),
    Case("trust", "view: artifact file deleted", _view_missing_file, check=names("keyframes")),
    Case(
        "sharing", "map.mcap: CRCs, summary, Foxglove schemas", _show("evaluate"), (0,), _mcap_valid
    ),
    Case("sharing", "PLY: vertex properties by plyfile", _show("voxelize"), (0,), _ply_readable),
]
