"""Shared fixtures: paths to the third-party data beside the checkout, the toy graph."""

from __future__ import annotations

import atexit
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.fixtures.shared_data import SHARED_DATA

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))

os.environ.setdefault("OMP_NUM_THREADS", "2")
# Model and dataset caches in a throwaway folder, never the user's (pipeline.training.cache_dir).
if not os.environ.get("SONARMAP_CACHE_DIR"):
    os.environ["SONARMAP_CACHE_DIR"] = tempfile.mkdtemp(prefix="sonarmap-test-cache-")
    atexit.register(shutil.rmtree, os.environ["SONARMAP_CACHE_DIR"], True)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Tests that read the third-party files carry the `shared_data` marker, so that
    `pytest -m shared_data` selects exactly them."""
    for item in items:
        if "shared_data" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.shared_data)


@pytest.fixture
def shared_data() -> Path:
    """`../shared/data` (third-party files); tests skip cleanly when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"third-party data not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture
def toy_cli(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """The CLI (in this process) runs the toy graph (`toy_stages.GRAPH`, named by
    $SONARMAP_GRAPH as a user would); returns a toy dataset file."""
    monkeypatch.setenv("SONARMAP_GRAPH", "toy_stages:GRAPH")
    data = tmp_path / "raw.bin"
    data.write_bytes(bytes(range(256)) * 4)
    return data


@pytest.fixture
def toy_env(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[list[Path]]:
    """Two toy datasets; the CLI and its sweep workers (other processes) run the toy graph."""
    monkeypatch.setenv("SONARMAP_GRAPH", "toy_stages:GRAPH")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT / "tests"), str(ROOT)]))
    monkeypatch.setenv("TOY_CALL_LOG", str(tmp_path / "calls.log"))
    datasets = []
    for i in range(2):
        d = tmp_path / f"d{i}.bin"
        d.write_bytes(bytes((j * (i + 1)) % 256 for j in range(512)))
        datasets.append(d)
    yield datasets


@pytest.fixture
def no_matplotlib(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every import of matplotlib fails during the test (as where it is not installed): the
    map stages compute without it, only the figure stages draw."""
    for name in [n for n in sys.modules if n == "matplotlib" or n.startswith("matplotlib.")]:
        monkeypatch.setitem(sys.modules, name, None)
    monkeypatch.setitem(sys.modules, "matplotlib", None)
