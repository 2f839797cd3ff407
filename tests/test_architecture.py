"""Imports flow one way: schemas <- stages <- pipeline, schemas <- sim <- pipeline."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

FORBIDDEN = {
    "stages": ("pipeline", "mcap", "mcap_ros2", "pyarrow.parquet", "typer", "sim"),
    "schemas": ("pipeline", "stages", "sim", "mcap", "pyarrow.parquet", "typer"),
    "sim": ("pipeline", "stages", "mcap", "pyarrow.parquet", "typer"),
}


def _imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.extend(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
            names.extend(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def _violations(package: str) -> list[str]:
    bad = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for name in _imports(path):
            for forbidden in FORBIDDEN[package]:
                if name == forbidden or name.startswith(forbidden + "."):
                    bad.append(f"{path.relative_to(ROOT)} imports {name}")
    return bad


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_package_never_imports_what_it_must_not(package: str) -> None:
    assert _violations(package) == []


def test_stages_never_print_or_open_files() -> None:
    bad = []
    for path in sorted((ROOT / "stages").rglob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Name)
                and node.func.id in ("print", "open")
            ):
                bad.append(f"{path.name}:{node.lineno} calls {node.func.id}()")
    assert bad == []


def test_the_checker_catches_a_violation(tmp_path: Path) -> None:
    sample = tmp_path / "x.py"
    sample.write_text("import pyarrow.parquet as pq\nfrom pipeline.store import ArtifactStore\n")
    names = _imports(sample)
    assert "pyarrow.parquet" in names and "pipeline.store" in names
