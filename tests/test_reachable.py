"""Every module under ``gnss_cli/`` is reached from an entry point: no dead module.

The entry points are the modules of the console scripts (``[project.scripts]`` of
``pyproject.toml``), the package itself (``gnss_cli/__init__.py``) and the Python API
(``gnss_cli/api.py``). From them the imports are followed through the sources (``ast``):
``import a.b``, ``from a import b`` (``a.b`` when it is a module), relative imports, imports
inside functions, and string constants naming a module (``"gnss_cli.x.y"``, or
``"gnss_cli.x.y:name"``, as handed to :mod:`importlib` or an entry point). Importing a module
runs its packages' ``__init__`` too. Imports under ``if TYPE_CHECKING:`` do not count: they
never run. Tests, benchmarks and doctests do not count either.
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "gnss_cli"
_MODULE_STRING = re.compile(r"^([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)+)(?::[\w.]+)?$")


def package_modules(package_dir: Path) -> dict[str, Path]:
    """Dotted name -> source file of every module of the package (a package is its ``__init__``)."""
    out = {}
    for path in sorted(package_dir.rglob("*.py")):
        parts = list(path.relative_to(package_dir.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _runtime_nodes(tree: ast.AST) -> list[ast.AST]:
    """Every node of ``tree`` except the bodies of ``if TYPE_CHECKING:`` (their ``else`` runs)."""
    out: list[ast.AST] = []
    stack = [tree]
    while stack:
        node = stack.pop()
        out.append(node)
        if isinstance(node, ast.If) and (
            (isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING")
            or (isinstance(node.test, ast.Attribute) and node.test.attr == "TYPE_CHECKING")
        ):
            stack.extend(node.orelse)
            continue
        stack.extend(ast.iter_child_nodes(node))
    return out


def imported_names(source: str, module: str, is_package: bool) -> set[str]:
    """Dotted names ``source`` (the module ``module``) may import: modules, or names in them."""
    package = module.split(".") if is_package else module.split(".")[:-1]
    names: set[str] = set()
    for node in _runtime_nodes(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            names.add(target)
            names.update(f"{target}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            match = _MODULE_STRING.match(node.value)
            if match:
                names.add(match.group(1))
    return names


def reachable(modules: dict[str, Path], roots: list[str]) -> set[str]:
    """The modules of ``modules`` that ``roots`` import, directly or not (with their packages)."""
    seen: set[str] = set()
    todo = list(roots)
    while todo:
        name = todo.pop()
        parts = name.split(".")
        for k in range(1, len(parts) + 1):  # a module's packages run first
            prefix = ".".join(parts[:k])
            if prefix in modules and prefix not in seen:
                seen.add(prefix)
                path = modules[prefix]
                todo.extend(imported_names(path.read_text(encoding="utf-8"), prefix, path.name == "__init__.py"))
    return seen


def entry_modules() -> list[str]:
    """The console scripts' modules, the package and its Python API."""
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["scripts"]
    return sorted({target.split(":")[0] for target in scripts.values()}) + ["gnss_cli", "gnss_cli.api"]


def test_every_module_is_reached_from_an_entry_point() -> None:
    modules = package_modules(PACKAGE)
    roots = entry_modules()
    assert "gnss_cli.cli.solve" in roots and set(roots) <= set(modules), roots
    unreached = sorted(set(modules) - reachable(modules, roots))
    assert not unreached, f"modules no entry point imports (dead code, or an import this scan misses): {unreached}"


def test_the_scan_follows_every_kind_of_import(tmp_path: Path) -> None:
    """Absolute, relative, in-function and string imports are followed; a module only imported
    for type checking, or imported by nothing, is reported."""
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    files = {
        "__init__.py": "",
        "main.py": "from . import rel\nimport pkg.absolute\ndef f():\n    from pkg.sub import inner\n",
        "rel.py": "import importlib\nimportlib.import_module('pkg.by_string')\n",
        "absolute.py": "from .sub.inner import thing\nENTRY = 'pkg.entry:main'\n",
        "by_string.py": "",
        "entry.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg import typing_only\n",
        "typing_only.py": "",
        "orphan.py": "import pkg.main\n",
        "sub/__init__.py": "",
        "sub/inner.py": "thing = 1\n",
        "sub/orphan2.py": "",
    }
    for name, text in files.items():
        (pkg / name).write_text(text)
    modules = package_modules(pkg)
    assert set(modules) - reachable(modules, ["pkg.main"]) == {"pkg.orphan", "pkg.typing_only", "pkg.sub.orphan2"}
