"""The one-way architecture (DESIGN.md section 6): a module imports only layers of equal or lower rank.

Every import of a gnss_cli module counts: ``import gnss_cli.x``, ``from gnss_cli import x``,
``from gnss_cli.x import y``, relative imports (resolved against the importing module) and
imports inside functions. Every module must have a rank; one without fails the check.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "gnss_cli"
# Rank of each layer (the first name below gnss_cli); a module may import gnss_cli modules of
# equal or lower rank only. "__init__" is the package's own gnss_cli/__init__.py (it may import
# anything: it is the top).
RANKS = {
    "errors": 0, "constants": 0, "io": 1, "gnss": 2, "config": 2, "solvers": 3, "behavior": 3,
    "sim": 4, "pipeline": 5, "report": 6, "stanford": 6, "plots": 6, "formats": 6, "api": 7, "cli": 8, "__init__": 9,
    "__version__": 0,  # the package's version string (metadata, importable from anywhere)
    "parallel": 0,  # forked worker processes: the standard library only, for any layer
}


def _module_name(path: Path, root: Path) -> str:
    """Dotted name of ``path`` below ``root`` (the folder holding the package)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts)


def _layer(module: str) -> str:
    """Layer of a dotted gnss_cli module name: its second part, ``__init__`` for the package itself."""
    parts = module.split(".")
    if len(parts) == 1 or parts[1] == "__init__":
        return "__init__"
    return parts[1]


def imported_modules(source: str, module: str, is_package: bool = False) -> list[tuple[int, str]]:
    """``(line, dotted name)`` of every gnss_cli module (or name in one) that ``source`` imports.

    ``module`` is the importing module's dotted name (``gnss_cli.io.x``); relative imports are
    resolved against its package (the module itself when ``is_package``, an ``__init__.py``).
    ``from a import b`` yields ``a.b`` so that ``from gnss_cli import cli`` names the layer.
    """
    package = module.split(".") if is_package else module.split(".")[:-1]
    out: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level > len(package):  # above gnss_cli: kept with its dots, reported as such
                target = "." * node.level + (node.module or "")
            elif node.level:
                base = package[: len(package) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            out += [(node.lineno, f"{target}.{alias.name}") for alias in node.names]
    return [(line, name) for line, name in out
            if name == "gnss_cli" or name.startswith("gnss_cli.") or name.startswith(".")]


def layer_violations(package_dir: Path) -> list[str]:
    """Every import against the ranks under ``package_dir``, and every module without a rank."""
    root = package_dir.parent
    problems: list[str] = []
    for path in sorted(package_dir.rglob("*.py")):
        module = _module_name(path, root)
        is_package = path.name == "__init__.py"
        if is_package:
            module = module[: -len(".__init__")]
        here = _layer(module) if module != package_dir.name else "__init__"
        rel = path.relative_to(root).as_posix()
        if here not in RANKS:
            problems.append(f"{rel}: layer {here!r} has no rank in RANKS")
            continue
        for line, name in imported_modules(path.read_text(encoding="utf-8"), module, is_package):
            there = _layer(name)
            if name.startswith("."):
                problems.append(f"{rel}:{line}: relative import {name} goes above the package")
            elif there not in RANKS:
                problems.append(f"{rel}:{line}: imports {name} (layer {there!r} has no rank)")
            elif RANKS[there] > RANKS[here]:
                problems.append(f"{rel}:{line}: imports {name} ({there} rank {RANKS[there]} > {here} rank {RANKS[here]})")
    return problems


def test_imports_flow_one_way():
    problems = layer_violations(PACKAGE)
    assert not problems, "layer violations:\n" + "\n".join(problems)


def _write(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root / "gnss_cli"


def test_planted_back_edges_are_reported(tmp_path):
    pkg = _write(tmp_path, {
        "gnss_cli/__init__.py": "def solve():\n    from gnss_cli import api\n    return api\n",
        "gnss_cli/errors.py": "",
        "gnss_cli/io/__init__.py": "",
        "gnss_cli/io/x.py": "from ..pipeline import run\n",
        "gnss_cli/io/y.py": "def f():\n    import gnss_cli.cli.solve\n",
        "gnss_cli/io/z.py": "from gnss_cli import report\nfrom . import x\nfrom ..errors import GnssError\n",
        "gnss_cli/pipeline/__init__.py": "from .run import run\n",
        "gnss_cli/pipeline/run.py": "from ..io import x\nfrom gnss_cli.gnss import frames\n",
        "gnss_cli/api.py": "from gnss_cli.report import table\n",
        "gnss_cli/cli/__init__.py": "",
        "gnss_cli/cli/solve.py": "from gnss_cli.api import solve\n",
        "gnss_cli/extra.py": "",
        "gnss_cli/report.py": "from ..pipeline import run\n",
    })
    assert layer_violations(pkg) == [
        "gnss_cli/extra.py: layer 'extra' has no rank in RANKS",
        "gnss_cli/io/x.py:1: imports gnss_cli.pipeline.run (pipeline rank 5 > io rank 1)",
        "gnss_cli/io/y.py:2: imports gnss_cli.cli.solve (cli rank 8 > io rank 1)",
        "gnss_cli/io/z.py:1: imports gnss_cli.report (report rank 6 > io rank 1)",
        "gnss_cli/report.py:1: relative import ..pipeline.run goes above the package",
    ]


def test_relative_imports_resolve_to_absolute_names():
    assert imported_modules("from ..pipeline import x\n", "gnss_cli.report") == [(1, "..pipeline.x")]  # above
    assert imported_modules("from ..pipeline import x\n", "gnss_cli.cli.solve") == [(1, "gnss_cli.pipeline.x")]
    assert imported_modules("from . import io\n", "gnss_cli", is_package=True) == [(1, "gnss_cli.io")]
    assert imported_modules("from .epochs import e\n", "gnss_cli.pipeline", is_package=True) == [
        (1, "gnss_cli.pipeline.epochs.e")
    ]


def test_only_io_imports_georinex():
    offenders = [
        str(p.relative_to(PACKAGE))
        for p in PACKAGE.rglob("*.py")
        if "georinex" in p.read_text() and "import georinex" in p.read_text().replace("from georinex", "import georinex")
        and p.parent.name != "io"
    ]
    assert not offenders, offenders
