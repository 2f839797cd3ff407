"""Cross-package imports inside `pipeline/`: sub-package -> sub-package edges, with counts.

A module's package is its first folder under `pipeline/` (a top-level module such as
`cli.py` is its own); `--depth 2` splits one level further (`engine.store`, ...). An
edge counts the imported names (function-level and `TYPE_CHECKING` imports included),
so it reads as "how much A leans on B".

    python benchmarks/import_edges.py [ROOT] [--depth N]
"""

from __future__ import annotations

import argparse
import ast
from collections import Counter
from pathlib import Path

PREFIX = "sonarmap.pipeline."


def _imports(path: Path) -> list[str]:
    names = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.extend(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
    return names


def _group(module: str, depth: int, packages: set[str]) -> str:
    """`engine.store.gc` -> `engine` (depth 1) or `engine.store` (depth 2, when that is a
    package; a module directly in `engine/` stays `engine`)."""
    parts = module.split(".")
    for n in range(min(depth, len(parts)), 0, -1):
        head = ".".join(parts[:n])
        if n == 1 or head in packages:
            return head
    return parts[0]


def edges(root: Path, depth: int = 1) -> Counter[tuple[str, str]]:
    base = root / "pipeline"
    packages = {
        ".".join(p.parent.relative_to(base).parts) for p in base.rglob("__init__.py")
    } - {""}
    found: Counter[tuple[str, str]] = Counter()
    for path in sorted(base.rglob("*.py")):
        rel = path.relative_to(base).with_suffix("").parts
        source = _group(".".join(p for p in rel if p != "__init__") or "__init__", depth, packages)
        for name in _imports(path):
            if not name.startswith(PREFIX):
                continue
            target = _group(name.removeprefix(PREFIX), depth, packages)
            if target != source:
                found[source, target] += 1
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", nargs="?", type=Path, default=Path(__file__).parent.parent)
    parser.add_argument("--depth", type=int, default=1)
    args = parser.parse_args()
    for (source, target), count in sorted(edges(args.root, args.depth).items()):
        print(f"{source:>24} -> {target:<24} {count}")


if __name__ == "__main__":
    main()
