"""The data walk of the dataset path: project modules crossed from `sonarmap run` to the
keyframes stage (issue 36's target: <= 6 modules, none entered twice).

Runs `sonarmap run RECORDING --until keyframes` in this process on a fresh store and
records the call stack whenever the dataset is fingerprinted (its parts listed), opened,
or handed to `sonarmap.stages.keyframes.stage.run`. Each stack is cut at the `run` command's frame and
read as the ordered project modules it passes through; the walk is their ordered union.
A module "entered twice" appears in one stack in two places with another module between.

    .venv/bin/python -m benchmarks.data_walk [RECORDING]

Without a recording it uses the QA campaign's small simulated one. Prints one JSON
document.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path
from types import CodeType, FrameType
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


def _module(filename: str) -> str | None:
    path = Path(filename).resolve()
    if not path.is_relative_to(ROOT) or "benchmarks" in path.relative_to(ROOT).parts[:1]:
        return None
    return ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")


def _stack(frame: FrameType | None, command: CodeType) -> list[str]:
    """Project modules from the `run` command's frame down to `frame` (outermost first)."""
    files: list[str] = []
    while frame is not None:
        files.append(frame.f_code.co_filename)
        if frame.f_code is command:
            break
        frame = frame.f_back
    modules = [m for m in map(_module, reversed(files)) if m is not None]
    return [m for i, m in enumerate(modules) if i == 0 or modules[i - 1] != m]


def main(argv: list[str]) -> dict[str, Any]:
    import sonarmap.pipeline.readers
    import sonarmap.stages.keyframes.stage
    from sonarmap.pipeline.cli import app
    from sonarmap.pipeline.commands import run as run_command

    if argv:
        recording = Path(argv[0])
    else:
        from tests.fixtures import small_recording

        recording = small_recording(Path(tempfile.mkdtemp()) / "rec.mcap", duration_s=45.0)
    command: CodeType | None = None  # the `run` command's code, found on its first call
    targets = {
        sonarmap.pipeline.readers.dataset_fingerprint_parts.__code__: "fingerprinted",
        sonarmap.pipeline.readers.open_recording.__code__: "opened",
        sonarmap.stages.keyframes.stage.run.__code__: "keyframes.run",
    }
    stacks: dict[str, list[str]] = {}

    def profile(frame: FrameType, event: str, _arg: Any) -> None:
        nonlocal command
        if event != "call":
            return
        code = frame.f_code
        if command is None and code.co_name == "run" and code.co_filename == run_command.__file__:
            command = code
        what = targets.get(frame.f_code)
        if what is not None and what not in stacks and command is not None:
            stacks[what] = _stack(frame, command)

    store = Path(tempfile.mkdtemp()) / "store"
    sys.setprofile(profile)
    try:
        app(["run", str(recording), "--store", str(store), "--until", "keyframes", "-q"])
    except SystemExit as done:
        if done.code:
            raise
    finally:
        sys.setprofile(None)
    walk: list[str] = []
    for what in ("fingerprinted", "opened", "keyframes.run"):
        walk += [m for m in stacks.get(what, []) if m not in walk]
    twice = sorted({m for s in stacks.values() for i, m in enumerate(s) if m in s[:i]})
    return {"modules": len(walk), "walk": walk, "entered_twice": twice, "stacks": stacks}


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1:]), indent=1))
