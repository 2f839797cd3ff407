"""Cases that only check the campaign itself runs: a missing recording is refused."""

from __future__ import annotations

from pathlib import Path

from tests.contract.case import Case


def _missing(work: Path) -> list[str]:
    return ["run", str(work / "missing.mcap")]


CASES = [Case("exit codes", "run of a missing recording", _missing)]
