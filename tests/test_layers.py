"""The one-way architecture (DESIGN.md section 6): each layer imports only layers to its left."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "gnss_cli"
# Rank of each layer; a module may import gnss_cli modules of equal or lower rank only.
RANKS = {
    "errors": 0, "constants": 0, "io": 1, "gnss": 2, "config": 2, "solvers": 3, "behavior": 3,
    "sim": 4, "pipeline": 5, "report": 6, "cli": 7,
}


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def test_imports_flow_one_way():
    violations = []
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        here = _layer(".".join(rel.parts))
        if here not in RANKS:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            for name in names:
                if name.startswith("gnss_cli."):
                    there = _layer(name)
                    if there in RANKS and RANKS[there] > RANKS[here]:
                        violations.append(f"{rel}: imports {name}")
    assert not violations, violations


def test_only_io_imports_georinex():
    offenders = [
        str(p.relative_to(PACKAGE))
        for p in PACKAGE.rglob("*.py")
        if "georinex" in p.read_text() and "import georinex" in p.read_text().replace("from georinex", "import georinex")
        and p.parent.name != "io"
    ]
    assert not offenders, offenders
