"""sonarmap installs like any Python package: the sdist builds a wheel that holds one
top-level package and every file the program reads at run time, and that wheel, installed
into a fresh virtual environment, runs the demo from a directory outside the checkout.

The fresh environment takes its third-party dependencies from this test's environment
(a path entry, so none of this environment's own `.pth` hooks, the editable sonarmap among
them, apply there); sonarmap itself comes only from the wheel.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import tarfile
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BUILD = "from setuptools import build_meta as b; import sys; print(b.{}(sys.argv[1]))"

pytestmark = pytest.mark.wheel


def _build(kind: str, source: Path, out: Path) -> Path:
    name = subprocess.run(
        [sys.executable, "-c", BUILD.format(kind), str(out)],
        cwd=source, capture_output=True, text=True, check=True,
    ).stdout.strip().splitlines()[-1]
    return out / name


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel built from the sdist (as `python -m build` does): a file the sdist
    forgets cannot reach the wheel either."""
    work = tmp_path_factory.mktemp("build")
    sdist = _build("build_sdist", ROOT, work)
    with tarfile.open(sdist) as archive:
        archive.extractall(work / "src", filter="data")
    (unpacked,) = (work / "src").iterdir()
    return _build("build_wheel", unpacked, work)


def test_the_wheel_holds_one_top_level_package_and_the_shipped_files(wheel: Path) -> None:
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert tops == {"sonarmap"}
    for shipped in (
        "sonarmap/configs/scenes/marina.yaml",
        "sonarmap/configs/sonars/oculus-m750d-750khz.yaml",
        "sonarmap/configs/model/lock.json",
        "sonarmap/configs/foxglove/sonarmap-layout.json",
        "sonarmap/configs/paper.yaml",
    ):
        assert shipped in names
    assert any(n.startswith("sonarmap/configs/model/train/") and n.endswith(".pt") for n in names)
    assert any(n.startswith("sonarmap/schemas/msg/") and n.endswith(".msg") for n in names)


def test_the_installed_wheel_runs_the_demo_outside_the_checkout(
    wheel: Path, tmp_path: Path
) -> None:
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = Path(
        subprocess.run(
            [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
            capture_output=True, text=True, check=True,
        ).stdout.strip()
    )
    (site / "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run(
        [python, "-m", "pip", "install", "-q", "--no-deps", "--no-index", str(wheel)],
        check=True, capture_output=True,
    )
    away = tmp_path / "elsewhere"
    away.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "SONARMAP_GRAPH")}
    env["SONARMAP_CACHE_DIR"] = str(tmp_path / "cache")
    found = subprocess.run(
        [python, "-c", "import sonarmap.pipeline.package_data as p; print(p.configs_dir())"],
        cwd=away, env=env, capture_output=True, text=True, check=True,
    ).stdout.strip()
    assert Path(found).is_relative_to(site), found
    shown = subprocess.run(
        [python, "-m", "pip", "show", "-f", "sonarmap"],
        cwd=away, env=env, capture_output=True, text=True, check=True,
    ).stdout
    files = [line.strip() for line in shown.split("Files:", 1)[1].splitlines() if line.strip()]
    assert {f.split("/")[0] for f in files if not f.startswith(("sonarmap-", "../"))} == {
        "sonarmap"
    }
    demo = subprocess.run(
        [venv / "bin" / "sonarmap", "demo", "--goals", "2", "--no-figures", "--json"],
        cwd=away, env=env, capture_output=True, text=True, timeout=600,
    )
    assert demo.returncode == 0, demo.stderr[-2000:]
    doc = json.loads(demo.stdout)
    assert {s["stage"] for s in doc["stages"]} >= {"keyframes", "slam", "voxelize", "evaluate"}
    assert (away / "data" / "demo" / "marina-seed0.mcap").is_file()
    assert doc["summary"]["voxels"]["semantic"] > 0
