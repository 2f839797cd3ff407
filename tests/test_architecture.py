"""Imports flow one way: schemas <- stages.kernels <- stages <- pipeline, and
schemas <- stages.kernels <- sim <- pipeline; a stage never imports another stage
(stages share through artifacts and the kernel layer). Inside `pipeline/`, the layers
of pyproject.toml's `[tool.importlinter]` contracts: engine <- formats <- readers <-
training <- graph <- api <- experiments/labels/live <- report_cli <- commands <- cli."""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parent.parent

P, S, SIM = "sonarmap.pipeline", "sonarmap.stages", "sonarmap.sim"
FORBIDDEN = {
    "stages": (P, "mcap", "mcap_ros2", "pyarrow.parquet", "typer", SIM),
    "schemas": (P, S, SIM, "mcap", "pyarrow.parquet", "typer"),
    "sim": (P, S, "mcap", "pyarrow.parquet", "typer"),
    "stages/kernels": (P, S, SIM, "mcap", "pyarrow.parquet", "typer"),
}
ALLOWED = {
    "sim": ("sonarmap.stages.kernels",),
    "stages/kernels": ("sonarmap.stages.kernels",),
}
"""Exceptions to FORBIDDEN: the kernel layer sits below the stages and the simulator."""

PENDING: dict[str, tuple[str, ...]] = {}
"""Imports that break a rule here until the named work lands; each must still exist
(`test_pending_exceptions_are_still_needed`), so an entry goes when its import does."""

SHARED = ("sonarmap.stages.base", "sonarmap.stages.kernels")
"""What every stage may import of `stages`: the stage contract and the kernel layer."""


def _pending(path: Path, name: str) -> bool:
    allowed = PENDING.get(str(path.relative_to(ROOT)), ())
    return any(name == a or name.startswith(a + ".") for a in allowed)


def _imports(path: Path) -> list[str]:
    """Modules a file imports (function bodies and `if TYPE_CHECKING:` blocks included)."""
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
            if any(name == a or name.startswith(a + ".") for a in ALLOWED.get(package, ())):
                continue
            if _pending(path, name):
                continue
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
    sample.write_text(
        "import pyarrow.parquet as pq\nfrom sonarmap.pipeline.engine.store.artifact_store import ArtifactStore\n"
    )
    names = _imports(sample)
    assert "pyarrow.parquet" in names and "sonarmap.pipeline.engine.store.artifact_store" in names


def _stage_of(path: Path) -> str | None:
    """The stage a file of `stages/` belongs to: its package or module name (None for
    the kernel layer and `stages/__init__.py`)."""
    parts = path.relative_to(ROOT / "stages").with_suffix("").parts
    return None if parts[0] in ("kernels", "__init__") else parts[0]


def _sibling_imports(path: Path) -> list[str]:
    """Imports of one file of stage X that reach into a stage Y != X (`sonarmap.stages.base` and
    `sonarmap.stages.kernels` are shared, not stages)."""
    own = _stage_of(path)
    bad = []
    for name in _imports(path):
        parts = name.removeprefix("sonarmap.").split(".")
        if not name.startswith("sonarmap.stages.") or parts[1] == own:
            continue
        if any(name == s or name.startswith(s + ".") for s in SHARED):
            continue
        bad.append(f"{path.relative_to(ROOT)} imports {name}")
    return bad


def test_a_stage_never_imports_another_stage() -> None:
    bad = [
        line
        for path in sorted((ROOT / "stages").rglob("*.py"))
        if _stage_of(path) is not None
        for line in _sibling_imports(path)
        if not _pending(path, line.rsplit(" ", 1)[1])
    ]
    assert bad == []


def test_the_stage_rule_catches_a_sibling_import(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fake_root = tmp_path
    stage = fake_root / "stages" / "submaps"
    stage.mkdir(parents=True)
    sample = stage / "x.py"
    sample.write_text(
        "from sonarmap.stages.base import Stage\n"
        "from sonarmap.stages.kernels.poses import pose_matrix\n"
        "from sonarmap.stages.submaps.config import SubmapsConfig\n"
        "def f():\n    from sonarmap.stages.infer.stage import learn_and_infer\n"
        "from sonarmap.stages.keyframes import posed_pairs\n"
    )
    monkeypatch.setattr(f"{__name__}.ROOT", fake_root)
    assert sorted(_sibling_imports(sample)) == [
        "stages/submaps/x.py imports sonarmap.stages.infer.stage",
        "stages/submaps/x.py imports sonarmap.stages.infer.stage.learn_and_infer",
        "stages/submaps/x.py imports sonarmap.stages.keyframes",
        "stages/submaps/x.py imports sonarmap.stages.keyframes.posed_pairs",
    ]


def test_pending_exceptions_are_still_needed() -> None:
    for rel, names in PENDING.items():
        imported = _imports(ROOT / rel)
        for name in names:
            assert any(i == name or i.startswith(name + ".") for i in imported), (rel, name)


PACKAGES = ("pipeline", "stages", "sim", "schemas")
MAX_LINES = 400
STAGE_PACKAGES = (
    "classify",
    "evaluate",
    "features",
    "figures",
    "fuse",
    "infer",
    "keyframes",
    "map_figures",
    "slam",
    "submaps",
    "voxelize",
)
"""Stages of more than one module: each is a package named after the stage."""


def _import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """Module -> the project modules it imports (function bodies and imports under
    `if TYPE_CHECKING:` included: a type-only circle is still two modules that cannot
    be read, or moved, one without the other)."""
    paths = {
        "sonarmap." + ".".join(p.relative_to(root).with_suffix("").parts).removesuffix(".__init__"): p
        for pkg in PACKAGES
        for p in (root / pkg).rglob("*.py")
    }
    return {
        name: {t for t in _imports(path) if t in paths and t != name}
        for name, path in paths.items()
    }


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle per strongly connected group of modules (iterative DFS, colours)."""
    found, state = [], dict.fromkeys(graph, 0)  # 0 new, 1 on the stack, 2 done
    for root in sorted(graph):
        if state[root]:
            continue
        stack = [(root, iter(sorted(graph[root])))]
        state[root] = 1
        while stack:
            node, children = stack[-1]
            child = next(children, None)
            if child is None:
                state[node] = 2
                stack.pop()
            elif state[child] == 1:
                names = [n for n, _ in stack]
                found.append([*names[names.index(child) :], child])
            elif state[child] == 0:
                state[child] = 1
                stack.append((child, iter(sorted(graph[child]))))
    return found


def _lint_imports(config: Path) -> bool:
    """import-linter's contracts of `config` (its report goes to stdout, shown on failure)."""
    import importlinter.api  # noqa: F401  (configures the library's settings on import)
    from importlinter.application.use_cases import lint_imports

    return bool(lint_imports(config_filename=str(config), cache_dir=None, no_logo=True))


def test_no_import_points_back_up_a_layer_of_the_pipeline() -> None:
    """Inside `pipeline/`, imports follow the layers of pyproject.toml's
    `[tool.importlinter]` contracts (the engine under everything, commands and cli on
    top; run and share over store and config inside the engine)."""
    assert _lint_imports(ROOT / "pyproject.toml")


def _layer_contract() -> dict[str, Any]:
    from importlinter.api import read_configuration

    contracts = read_configuration(str(ROOT / "pyproject.toml"))["contracts_options"]
    return next(c for c in contracts if c.get("id") == "pipeline-layers")


@pytest.mark.parametrize("upward", [None, "fake.engine", "fake.readers", "fake.training"])
def test_the_layer_contract_catches_an_import_pointing_up(
    upward: str | None, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The project's layer list on a package of empty modules of the same names: clean it
    passes; one function-level import from a low layer up to `commands` breaks it."""
    import re

    layers = _layer_contract()["layers"]
    names = [n.strip() for layer in layers for n in re.split(r"[|:]", layer)]
    package = tmp_path / "fake"
    package.mkdir()
    (package / "__init__.py").write_text("")
    for name in names:
        (package / name).mkdir()
        (package / name / "__init__.py").write_text("")
    (package / "commands" / "__init__.py").write_text("from fake.engine import x\n")
    (package / "engine" / "x.py").write_text("")
    if upward is not None:
        module = package.joinpath(*upward.split(".")[1:], "__init__.py")
        module.write_text("def f():\n    from fake.commands import run\n")
    listed = ", ".join(f'"{layer}"' for layer in layers)
    config = tmp_path / "layers.toml"
    config.write_text(
        '[tool.importlinter]\nroot_packages = ["fake"]\n\n'
        '[[tool.importlinter.contracts]]\nname = "fake layers"\ntype = "layers"\n'
        f'containers = ["fake"]\nlayers = [{listed}]\n'
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    assert _lint_imports(config) is (upward is None)


def test_no_import_cycles() -> None:
    assert _cycles(_import_graph()) == []


def test_a_circle_through_a_type_only_import_counts(tmp_path: Path) -> None:
    pkg = tmp_path / "pipeline"
    pkg.mkdir()
    (pkg / "a.py").write_text("from sonarmap.pipeline.b import B\n")
    typed = (
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
        "    from sonarmap.pipeline.a import A\n"
    )
    (pkg / "b.py").write_text(typed)
    cycle = ["sonarmap.pipeline.a", "sonarmap.pipeline.b", "sonarmap.pipeline.a"]
    assert _cycles(_import_graph(tmp_path)) == [cycle]


def test_the_cycle_finder_finds_a_cycle() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "c", "a"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_source_file_over_the_line_limit() -> None:
    long = [
        f"{p.relative_to(ROOT)}: {n} lines"
        for pkg in PACKAGES
        for p in sorted((ROOT / pkg).rglob("*.py"))
        if (n := len(p.read_text().splitlines())) > MAX_LINES
    ]
    assert long == []


@pytest.mark.parametrize("name", STAGE_PACKAGES)
def test_a_multi_module_stage_is_a_package_exposing_its_stage(name: str) -> None:
    import importlib

    package = ROOT / "stages" / name
    assert (package / "__init__.py").is_file() and not (ROOT / "stages" / f"{name}.py").exists()
    assert importlib.import_module(f"sonarmap.stages.{name}").STAGE.name == name


def test_every_stage_package_is_listed_and_every_registered_stage_lives_in_stages() -> None:
    from sonarmap.pipeline.graph import pipeline_stages

    packages = sorted(
        p.parent.name for p in (ROOT / "stages").glob("*/__init__.py") if p.parent.name != "kernels"
    )
    assert packages == sorted(STAGE_PACKAGES)
    modules = {p.stem for p in (ROOT / "stages").glob("*.py")} | set(packages)
    assert {s.name for s in pipeline_stages()} <= modules


def test_pipeline_groups_engine_formats_training_and_experiments() -> None:
    top = sorted(p.name for p in (ROOT / "pipeline").glob("*.py"))
    assert top == [
        "__init__.py", "__main__.py", "api.py", "cli.py", "graph.py", "package_data.py",
        "report_cli.py", "scoring.py", "tables.py",
    ]
    for sub in ("engine", "formats", "training", "experiments", "readers", "commands"):
        assert (ROOT / "pipeline" / sub / "__init__.py").is_file()


def test_declaring_the_stages_imports_no_heavy_library() -> None:
    """Planning imports every stage package (its config and `STAGE`), never its
    computation: no numpy, pyarrow, torch, scipy, ... (decision 020). Checked in a fresh
    interpreter, since this one has imported everything by now."""
    import json
    import subprocess
    import sys

    heavy = ("numpy", "pyarrow", "torch", "scipy", "open3d", "sklearn", "gtsam", "kiss_icp")
    script = (
        "import importlib, json, sys\n"
        f"for name in {STAGE_PACKAGES!r}:\n"
        "    assert importlib.import_module('sonarmap.stages.' + name).STAGE.name == name\n"
        "assert importlib.import_module('sonarmap.stages.classify.training').STAGE.name == 'train'\n"
        f"print(json.dumps(sorted({{m.split('.')[0] for m in sys.modules}} & set({heavy!r}))))\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, check=True
    )
    assert json.loads(proc.stdout) == []


def test_a_deferred_stage_entry_point_resolves_and_pickles() -> None:
    """Each stage's `run` names a function that exists (a renamed one fails here, not in
    the middle of a run) and travels to a worker process by name."""
    import pickle

    from sonarmap.pipeline.graph import default_graph
    from sonarmap.stages.kernels.lazy import resolve

    for stage in default_graph().config_stages:
        ref = getattr(stage.run, "ref", None)
        if ref is not None:
            assert callable(resolve(ref)), ref
            assert pickle.loads(pickle.dumps(stage.run)) == stage.run
        for output in stage.outputs:
            if output.kind == "parquet" and output.schema is not None:
                assert output.arrow_schema.names, (stage.name, output.name)
