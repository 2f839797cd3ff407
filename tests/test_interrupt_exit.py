"""An interrupted command exits 130 (Ctrl-C) or 143 (SIGTERM) whatever its abandoned stage
thread holds: Open3D's leak check at C++ exit turned both into 1 and wrote a memory report
on stdout (campaign 13 #6: Ctrl-C during evaluation with `-j 2`)."""

from __future__ import annotations

import subprocess
import sys

import pytest

# `main()` around a command that is interrupted while a stage thread (a daemon, as the
# runner's are) still holds an Open3D tensor, as evaluation's ray casting does.
_SCRIPT = """
import sys, threading, time
import open3d as o3d
import sonarmap.pipeline.cli as cli

held = threading.Event()

def stage():
    tensor = o3d.core.Tensor.ones((1000,))
    held.set()
    time.sleep(60)

def interrupted_command():
    threading.Thread(target=stage, daemon=True).start()
    held.wait()
    print("stdout before the interrupt", flush=False)
    raise SystemExit(int(sys.argv[1]))

cli.app = interrupted_command
cli.main()
"""


@pytest.mark.parametrize("status", [130, 143])
def test_an_interrupt_keeps_its_status_and_stdout(status: int) -> None:
    done = subprocess.run(
        [sys.executable, "-c", _SCRIPT, str(status)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == status, done.stdout[-500:] + done.stderr[-500:]
    assert done.stdout == "stdout before the interrupt\n"  # flushed, no Open3D report


def test_other_statuses_leave_as_before() -> None:
    """Only the interrupt statuses skip the C++ teardown: an error's 2 is Python's own."""
    done = subprocess.run(
        [sys.executable, "-c", _SCRIPT.replace("daemon=True", "daemon=False").replace(
            "time.sleep(60)", "del tensor"), "2"],
        capture_output=True,
        text=True,
        timeout=60,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr[-500:]
