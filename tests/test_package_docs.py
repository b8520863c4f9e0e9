"""Every package docstring lists every module of its package (a module nobody lists is a module
nobody finds), and lists no module that is gone."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "gnss_cli"
PACKAGES = sorted(p.parent for p in PACKAGE.glob("*/__init__.py"))


@pytest.mark.parametrize("package", PACKAGES, ids=[p.name for p in PACKAGES])
def test_the_package_docstring_lists_its_modules(package: Path) -> None:
    doc = ast.get_docstring(ast.parse((package / "__init__.py").read_text())) or ""
    assert "Modules" in doc, f"{package.name}/__init__.py has no module list"
    block = doc[doc.index("Modules"):]
    listed = set(re.findall(r"^    (\w+)\s", block, flags=re.M))
    modules = {p.stem for p in package.glob("*.py") if p.stem != "__init__"}
    assert modules - listed == set(), f"{package.name}: not listed"
    assert listed - modules == set(), f"{package.name}: listed but gone"
