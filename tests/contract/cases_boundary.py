"""The typed stage boundary: stages refusing their inputs, bad `sensors.json` records,
bad `$SONARMAP_GRAPH` values (issue 36).

Refusals run on a small graph defined here (named by `$SONARMAP_GRAPH`, as a user's
experiment would); `sensors.json` cases take the small simulated recording through
`features` while preparing, then rewrite its `sensors.json` (and the manifest's sha256,
as a consistent artifact from a remote would be) so the timed run refuses it when
`fuse` binds it.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.pipeline.engine.run.graph import Graph
from sonarmap.stages.base import DATASET, Input, Output, Stage, StageConfig, StageInputError
from tests.contract.case import Case, names
from tests.fixtures import ROOT, small_recording

STORE = "data/store"
ENV = {
    "SONARMAP_GRAPH": "tests.contract.cases_boundary:GRAPH",
    "PYTHONPATH": str(ROOT),
}


class _Config(StageConfig):
    refuse: str = ""
    """What the stage does: "" nothing, "dataset"/"upstream"/"long"/"escapes": refuse that
    input, "bug": raise a plain ValueError (a bug in the stage: exit 1)."""


_REASONS = {
    "dataset": "the sonar never overlaps the navigation (pings 0-99 s, navigation 500-900 s)",
    "upstream": "column v has nulls\nTraceback (most recent call last): not a traceback",
    "long": "x" * 5000,
    "escapes": "bad \x1b[31mred\x1b[0m value \r\x07 with control characters",
}


def _first(config: _Config, inputs: dict[str, Any]) -> dict[str, Any]:
    if config.refuse == "dataset":
        raise StageInputError(DATASET, _REASONS["dataset"])
    n = len(inputs["dataset"])
    return {"table": pa.table({"v": np.arange(n, dtype=np.int64)})}


def _second(config: _Config, inputs: dict[str, Any]) -> dict[str, Any]:
    if config.refuse == "bug":
        raise ValueError("an index out of range (a bug)")
    if config.refuse in _REASONS and config.refuse != "dataset":
        raise StageInputError(Input("first", "table"), _REASONS[config.refuse])
    return {"summary": {"rows": inputs["first.table"].num_rows}}


def _parts(path: Path) -> list[Path]:
    return [path]


def _open(path: Path, _section: Any) -> bytes:
    return path.read_bytes()


GRAPH = Graph(
    stages=(
        Stage("first", 1, _Config, (DATASET,), (Output("table", "parquet", "t.parquet"),), _first),
        Stage(
            "second",
            1,
            _Config,
            (Input("first", "table"),),
            (Output("summary", "json", "s.json"),),
            _second,
        ),
    ),
    parts=_parts,
    open=_open,
)


def _refusal(refuse: str, stage: str) -> Any:
    def build(work: Path) -> list[str]:
        (work / "rec.bin").write_bytes(b"ping" * 64)
        return ["run", "rec.bin", "--store", STORE, "--set", f"{stage}.refuse={refuse}"]

    return build


def _names(file: str) -> Any:
    """Check: the one error line names `file` (the recording or an artifact's file), and no
    control character reached the terminal."""
    named = names(file)

    def check(work: Path, proc: subprocess.CompletedProcess[str]) -> str | None:
        if "\x1b" in proc.stderr or "\x07" in proc.stderr:
            return "control characters reached the terminal"
        return named(work, proc)

    return check


def _kept(work: Path, proc: subprocess.CompletedProcess[str]) -> str | None:
    """Check: the stage before the refusing one is still in the store."""
    found = list((work / STORE / "first").glob("*/manifest.json"))
    return None if found else "the computed first stage was lost"


def _graph_env(value: str) -> Any:
    def build(work: Path) -> list[str]:
        (work / "rec.bin").write_bytes(b"ping")
        return ["status", "rec.bin", "--store", STORE]

    return build


_BASE: dict[str, Path] = {}


def _features_store() -> Path:
    """A store holding the small recording's keyframes and features (made once)."""
    if "store" not in _BASE:
        base = ROOT / "data" / "qa" / "boundary"
        rec = small_recording(base / "rec.mcap", duration_s=45.0)
        store = base / "store"
        if not list((store / "features").glob("*/manifest.json")):
            cmd = [
                sys.executable,
                "-m",
                "sonarmap.pipeline",
                "run",
                str(rec),
                "--store",
                str(store),
            ]
            env = {**os.environ, "PYTHONPATH": str(ROOT)}
            subprocess.run([*cmd, "--until", "features", "-q"], env=env, check=True)
        _BASE["store"], _BASE["rec"] = store, rec
    return _BASE["store"]


def _sensors(change: Any) -> Any:
    """A store whose keyframes' sensors.json is rewritten by `change(doc)`, with the
    manifest's sha256 and size updated to match (a consistent artifact)."""

    def build(work: Path) -> list[str]:
        shutil.copytree(_features_store(), work / STORE)
        shutil.copyfile(_BASE["rec"], work / "rec.mcap")
        (art,) = (work / STORE / "keyframes").glob("*/manifest.json")
        doc = json.loads((art.parent / "sensors.json").read_text())
        data = json.dumps(change(doc)).encode()
        (art.parent / "sensors.json").write_bytes(data)
        manifest = json.loads(art.read_text())
        manifest["files"]["sensors.json"] = {
            "sha256": hashlib.sha256(data).hexdigest(),
            "size": len(data),
        }
        art.write_text(json.dumps(manifest, indent=2, sort_keys=True))
        return ["run", "rec.mcap", "--store", STORE, "--until", "fuse", "-q"]

    return build


def _set(role: str, value: Any) -> Any:
    return lambda doc: {**doc, role: {"T_base_sonar": value}}


_SCALED = (2 * np.eye(4)).tolist()
_NAN = [[float("nan")] * 4] * 4
_SENSORS = (
    ("a non-rigid vertical mounting", _set("vertical", _SCALED)),
    ("a 3x3 horizontal mounting", _set("horizontal", np.eye(3).tolist())),
    ("a mounting of strings", _set("horizontal", [["1"] * 4] * 4)),
    ("a NaN mounting", _set("vertical", _NAN)),
    ("no vertical sonar", lambda doc: {k: v for k, v in doc.items() if k != "vertical"}),
    ("has_labels as a string", lambda doc: {**doc, "has_labels": "yes"}),
    ("sensors.json as a list", lambda doc: [doc]),
    ("a huge mounting", _set("horizontal", [[1.0] * 4] * 4000)),
)

CASES = [
    Case(
        "exit codes",
        "a stage refuses the recording (sonar never overlaps navigation)",
        _refusal("dataset", "first"),
        check=_names("rec.bin"),
        env=ENV,
    ),
    Case(
        "exit codes",
        "a stage refuses an upstream artifact with a two-line reason",
        _refusal("upstream", "second"),
        check=lambda w, p: _names("/t.parquet")(w, p) or _kept(w, p),
        env=ENV,
    ),
    Case(
        "exit codes",
        "a stage refuses an input with a 5000-character reason",
        _refusal("long", "second"),
        check=_names("/t.parquet"),
        env=ENV,
    ),
    Case(
        "exit codes",
        "a stage refuses an input with escape sequences in its reason",
        _refusal("escapes", "second"),
        check=_names("/t.parquet"),
        env=ENV,
    ),
    Case(
        "exit codes",
        "a stage's own ValueError stays a bug (exit 1, one line)",
        _refusal("bug", "second"),
        expect_exit=(1,),
        check=lambda w, p: _kept(w, p) if "stage second failed" in p.stderr else "no stage named",
        env=ENV,
    ),
    *(
        Case(
            "exit codes",
            f"$SONARMAP_GRAPH={value}",
            _graph_env(value),
            env={**ENV, "SONARMAP_GRAPH": value},
        )
        for value in (
            "no_such_module:GRAPH",
            "os:path",
            "sonarmap.pipeline.engine.run.graph:GRAPH_ENV",
            ":",
        )
    ),
    *(
        Case(
            "trust",
            f"keyframes' sensors.json with {name}",
            _sensors(change),
            check=_names("/sensors.json"),
        )
        for name, change in _SENSORS
    ),
]
