"""The documentation holds together: every document the code cites is in the repository,
the README stays a short front door, the site's nav and links resolve, and the generated
references (CLI, config, columns) cover every command, config section and schema.

`make docs` builds the site itself (`mkdocs build --strict`); these checks need no MkDocs.
"""

from __future__ import annotations

import importlib.util
import re
import unicodedata
from pathlib import Path
from types import ModuleType

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
SOURCE_DIRS = ("pipeline", "stages", "schemas", "sim", "configs")
SOURCE_SUFFIXES = {".py", ".yaml", ".yml", ".json", ".md"}

WRITTEN_FILES = {"report.md", "table.md", "table_i.md"}
"""Markdown files sonarmap writes (a report, a study's tables): names, not citations."""

MD_REFERENCE = re.compile(r"[\w./-]*[\w-]\.md(?:#[\w-]+)?")
OUTSIDE_DOCUMENTS = re.compile(
    r"DESIGN(?:\.md)?\b|original-implementation|ecosystem\.md|STYLE\.md|style-anchors"
    r"|shared/(?:data|reference|paper)|\.\./shared"
)
"""Documents that live beside the repository, not in it: a user's clone has none."""

ISSUE_NUMBER = re.compile(r"\bissues?\s*#?\s*\d+|(?<![\w&])#\d{1,4}\b", re.IGNORECASE)
MD_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def _source_files() -> list[Path]:
    files = []
    for folder in SOURCE_DIRS:
        files += [
            p
            for p in sorted((ROOT / folder).rglob("*"))
            if p.suffix in SOURCE_SUFFIXES and p.is_file() and "__pycache__" not in p.parts
        ]
    return files


def _slug(heading: str) -> str:
    """Python-Markdown's `toc` slug of a heading (what MkDocs anchors are)."""
    # Code spans keep their underscores (extend_units.py -> extend_unitspy): only the
    # backticks, emphasis stars and a link's target go.
    text = re.sub(r"[`*]|\[([^\]]*)\]\([^)]*\)", r"\1", heading)
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode()
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def _anchors(page: Path) -> set[str]:
    text = re.sub(r"(?ms)^```.*?^```", "", page.read_text(encoding="utf-8"))
    return {_slug(m.group(1)) for m in re.finditer(r"(?m)^#{1,6}\s+(.+?)\s*$", text)}


def _resolve(reference: str) -> tuple[Path, str]:
    path, _, anchor = reference.partition("#")
    if "/" not in path and re.match(r"\d{3}-", path):
        return DOCS / "decisions" / path, anchor  # a decision note by its file name
    return ROOT / path, anchor


def _hooks() -> ModuleType:
    spec = importlib.util.spec_from_file_location("sonarmap_docs_hooks", DOCS / "hooks.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def hooks() -> ModuleType:
    return _hooks()


def _user_pages() -> list[Path]:
    """The hand-written site pages and the README (decision notes keep their history)."""
    pages = [p for p in sorted(DOCS.rglob("*.md")) if "decisions" not in p.parts]
    assert len(pages) >= 12, pages
    return [ROOT / "README.md", *pages]


def test_every_document_the_code_cites_is_in_the_repository() -> None:
    files = _source_files()
    assert len(files) > 100, "the source folders were not found"
    cited = 0
    missing = []
    for path in files:
        text = path.read_text(encoding="utf-8", errors="replace")
        where = path.relative_to(ROOT)
        for m in OUTSIDE_DOCUMENTS.finditer(text):
            line = text.count("\n", 0, m.start()) + 1
            missing.append(f"{where}:{line}: cites {m.group(0)!r}, which is not in the repository")
        for m in MD_REFERENCE.finditer(text):
            reference = m.group(0)
            if reference.split("#")[0].rsplit("/", 1)[-1] in WRITTEN_FILES:
                continue
            cited += 1
            target, anchor = _resolve(reference)
            line = text.count("\n", 0, m.start()) + 1
            if not target.is_file():
                missing.append(f"{where}:{line}: {reference}: no such file")
            elif anchor and anchor not in _anchors(target):
                missing.append(f"{where}:{line}: {reference}: no heading with that anchor")
    assert not missing, "\n".join(missing)
    assert cited >= 20, f"only {cited} citations found: the pattern no longer matches them"


def test_readme_is_a_short_front_door() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 200
    for needed in ("make demo", "make test", "make docs", "pip install .", "sonarmap demo"):
        assert needed in text, needed


def test_user_documentation_names_no_issue_number() -> None:
    found = []
    for page in _user_pages():
        for n, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
            for m in ISSUE_NUMBER.finditer(line):
                found.append(f"{page.relative_to(ROOT)}:{n}: {m.group(0)!r}")
    assert not found, "\n".join(found)


def test_links_of_the_readme_and_the_site_pages_resolve(hooks: ModuleType) -> None:
    generated = {(DOCS / page).resolve() for page in hooks.GENERATED}
    broken = []
    checked = 0
    for page in _user_pages():
        for m in MD_LINK.finditer(page.read_text(encoding="utf-8")):
            link = m.group(1)
            if re.match(r"[a-z][a-z0-9+.-]*:", link):  # http(s):, mailto:
                continue
            path, _, anchor = link.partition("#")
            target = (page.parent / path).resolve() if path else page
            checked += 1
            if target in generated:  # built by docs/hooks.py, covered by the tests below
                continue
            if not target.is_file():
                broken.append(f"{page.relative_to(ROOT)}: {link}: no such file")
            elif anchor and target.suffix == ".md" and anchor not in _anchors(target):
                broken.append(f"{page.relative_to(ROOT)}: {link}: no such anchor")
    assert not broken, "\n".join(broken)
    assert checked >= 30


def test_the_readme_picture_is_small() -> None:
    images = [m.group(1) for m in MD_LINK.finditer((ROOT / "README.md").read_text()) if m.group(0).startswith("!")]
    assert images
    for image in images:
        assert (ROOT / image).stat().st_size < 300_000, image


def _nav_files(node: object) -> list[str]:
    if isinstance(node, str):
        return [node]
    if isinstance(node, dict):
        return [f for value in node.values() for f in _nav_files(value)]
    if isinstance(node, list):
        return [f for item in node for f in _nav_files(item)]
    return []


def test_every_nav_page_of_the_site_exists() -> None:
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))
    assert config["docs_dir"] == "docs" and config["strict"] is True
    assert (ROOT / config["hooks"][0]).is_file()
    generated = set(_hooks().GENERATED)
    nav = _nav_files(config["nav"])
    assert len(nav) >= 15
    missing = [f for f in nav if f not in generated and not (DOCS / f).is_file()]
    assert not missing, missing
    assert generated <= set(nav), "a generated reference is not in the nav"


def test_the_cli_reference_covers_every_command(hooks: ModuleType) -> None:
    import typer

    from sonarmap.pipeline.cli import app

    text = hooks.cli_markdown()
    root = typer.main.get_command(app)
    for name, command in root.commands.items():  # type: ignore[attr-defined]
        assert f"## `sonarmap {name}`" in text, name
        for sub in getattr(command, "commands", {}):
            assert f"## `sonarmap {name} {sub}`" in text, (name, sub)
    assert "`--set`" in text or "--set" in text


def test_the_config_reference_covers_every_section_and_key(hooks: ModuleType) -> None:
    registry = hooks._registry()
    text = hooks.config_markdown()
    sections = {s.name: s.config for s in registry.all_stages()}
    sections.update(registry.extra_sections())
    assert {"keyframes", "fuse", "infer", "train", "training", "classes"} <= set(sections)
    for name, model in sections.items():
        assert f"## `{name}`" in text, name
        for key in model.model_fields:
            assert f"| `{key}` |" in text, f"{name}.{key}"
    # Descriptions come from `Field(description=...)` or the class's `Attributes:` section.
    assert "new keyframe after this much travel" in text  # keyframes.spacing_m (docstring)


def test_the_column_reference_covers_every_schema(hooks: ModuleType) -> None:
    from sonarmap.schemas.keyframes import KEYFRAMES_SCHEMA
    from sonarmap.schemas.map import MAP_SCHEMA

    text = hooks.columns_markdown()
    for schema in (KEYFRAMES_SCHEMA, MAP_SCHEMA):
        for field in schema:
            assert f"| `{field.name}` |" in text, field.name
    assert "### `SUBMAP_FRAMES_SCHEMA`" in text


DOTTED = re.compile(r"\bsonarmap\.(?:pipeline|stages|schemas|sim|configs)(?:\.[A-Za-z_]\w*)*")


def _resolves(dotted: str) -> bool:
    """The longest importable module prefix of `dotted`, then attributes for the rest."""
    import importlib

    parts = dotted.split(".")
    for cut in range(len(parts), 1, -1):
        try:
            found: object = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for attr in parts[cut:]:
            if not hasattr(found, attr):
                return False
            found = getattr(found, attr)
        return True
    return False


def test_every_module_path_the_docs_and_docstrings_name_exists() -> None:
    """A module moved or renamed without its mentions fails here (`docs/decisions/` are
    dated notes and keep the names of their day)."""
    pages = [p for p in _user_pages() if "decisions" not in p.parts]
    code = [p for p in _source_files() if p.suffix == ".py"]
    named = {(m, p.name) for p in {*pages, *code} for m in DOTTED.findall(p.read_text())}
    assert sorted((m, f) for m, f in named if not _resolves(m)) == []
