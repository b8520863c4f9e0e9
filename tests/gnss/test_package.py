"""The gnss package docstring lists every module with its one job, in an order its imports follow:
a module imports only modules listed above it, so the package has no import cycle."""

from __future__ import annotations

import ast
from pathlib import Path

import gnss_cli.gnss

PACKAGE = Path(gnss_cli.gnss.__file__).parent


def listed_modules(doc: str) -> list[str]:
    """The module names of a package docstring's ``Modules, one job each::`` block, in order
    (entries indented by four spaces; deeper lines continue the entry above)."""
    block = doc.split("::", 1)[1]
    return [line.split()[0] for line in block.splitlines() if line.startswith("    ") and line[4] != " "]


def gnss_imports(path: Path) -> set[str]:
    """The ``gnss_cli.gnss`` modules ``path`` imports, wherever the import is (``TYPE_CHECKING`` too)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module:
            parts = node.module.split(".")
            if parts[:2] == ["gnss_cli", "gnss"]:
                names |= {parts[2]} if len(parts) > 2 else {a.name for a in node.names}
        elif isinstance(node, ast.Import):
            names |= {a.name.split(".")[2] for a in node.names if a.name.startswith("gnss_cli.gnss.")}
    return names


def test_the_docstring_lists_every_module_once():
    listed = listed_modules(gnss_cli.gnss.__doc__ or "")
    files = sorted(p.stem for p in PACKAGE.glob("*.py") if p.stem != "__init__")
    assert sorted(listed) == files and len(set(listed)) == len(listed)


def test_modules_import_only_modules_listed_above_them():
    order = listed_modules(gnss_cli.gnss.__doc__ or "")
    late = [f"{m} imports {i}" for k, m in enumerate(order) for i in sorted(gnss_imports(PACKAGE / f"{m}.py"))
            if i not in order[:k]]
    assert not late, late


def test_the_checks_see_a_planted_cycle(tmp_path):
    (tmp_path / "a.py").write_text("from gnss_cli.gnss.b import f\n")
    (tmp_path / "b.py").write_text("if True:\n    from gnss_cli.gnss import a\nimport gnss_cli.gnss.c\n")
    assert gnss_imports(tmp_path / "a.py") == {"b"} and gnss_imports(tmp_path / "b.py") == {"a", "c"}
    doc = "Title.\n\nModules::\n\n    a   one\n        continued\n    b   two\n"
    assert listed_modules(doc) == ["a", "b"]
