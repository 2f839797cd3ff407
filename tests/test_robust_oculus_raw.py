"""Raw Oculus captures are read one message at a time (issue 52, root 1): memory stays
one ping whatever the file's size or its headers' claims."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.readers import open_source

GIB = 1 << 30
# A child that may not map more than this: a capture read whole would not fit.
PROBE = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (1536 << 20, 1536 << 20))
from sonarmap.pipeline.readers import open_source
src = open_source(__import__("pathlib").Path(sys.argv[1]))
print(src.topics()[0].count, sum(1 for _ in src.messages(["/oculus/ping"])))
print(src.warnings[0] if src.warnings else "")
"""


def _ping(shared_data: Path) -> bytes:
    return (shared_data / "oculus" / "one_ping_8bit.raw").read_bytes()


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity"), reason="RLIMIT_AS is Linux's")
def test_a_capture_larger_than_memory_allows_is_streamed(shared_data: Path, tmp_path: Path) -> None:
    ping = _ping(shared_data)
    big = tmp_path / "big.raw"
    with big.open("wb") as f:
        f.write(ping * 3)
        f.truncate(3 * GIB)  # sparse: 3 GiB of zeros after three pings, no disk used
    out = subprocess.run(
        [sys.executable, "-c", PROBE, str(big)], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr[-2000:]
    counts, warning = out.stdout.splitlines()
    assert counts == "3 3"
    assert f"{3 * GIB - 3 * len(ping)} trailing bytes unreadable" in warning


def test_a_ping_claiming_more_than_the_cap_is_refused_unread(
    shared_data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ping = bytearray(_ping(shared_data))
    huge = tmp_path / "huge.raw"
    # payload_size (u32 at byte 10) claims 4 GiB; the file holds one real ping's bytes.
    ping[10:14] = struct.pack("<I", 0xFFFFFFF0)
    huge.write_bytes(bytes(ping))
    with pytest.raises(SourceError, match=r"huge\.raw: ping at byte 0 declares .*over the limit"):
        open_source(huge)
    monkeypatch.setenv("SONARMAP_MAX_CHUNK_MB", "8192")
    with pytest.raises(SourceError, match=r"huge\.raw: ping at byte 0 is cut short"):
        open_source(huge)


def test_a_capture_changed_after_opening_is_a_source_error(
    shared_data: Path, tmp_path: Path
) -> None:
    ping = _ping(shared_data)
    path = tmp_path / "two.raw"
    path.write_bytes(ping * 2)
    src = open_source(path)
    path.write_bytes(ping + b"\0" * len(ping))
    with pytest.raises(SourceError, match=r"two\.raw: ping 1: "):
        list(src.messages(["/oculus/ping"]))
