"""A clone without `../shared` beside it passes its tests: every test that reads the
third-party files takes them from the `shared_data` fixture, which skips with its reason
when the folder is absent (`make test-without-shared` runs those tests with it hidden).
The folder's path is built in one place, `tests/fixtures/shared_data.py`."""

from __future__ import annotations

import re
from pathlib import Path

TESTS = Path(__file__).resolve().parent
_SHARED_PATH = re.compile(r"""["']shared["']|SHARED_DATA\s*=[^=]""")


def test_only_the_fixture_names_the_shared_folder() -> None:
    offenders = [
        f"{path.name}:{number}"
        for path in sorted(TESTS.rglob("*.py"))
        if path.name not in ("conftest.py", "shared_data.py", Path(__file__).name)
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if _SHARED_PATH.search(line)
    ]
    assert offenders == [], "read ../shared/data through the shared_data fixture"


def test_the_guard_sees_a_hand_built_path() -> None:
    line = 'DATA = Path(__file__).resolve().parents[2] / "shared" / "data"'
    assert _SHARED_PATH.search(line)
