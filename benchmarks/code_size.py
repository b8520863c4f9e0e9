"""Largest modules and functions of gnss_cli, checked against the function size limit.

Prints the ``--top`` largest modules (lines) and functions (lines, with file:line) and exits 1
when a function (``def`` to its last line, docstring included) is over :data:`FUNCTION_MAX_LINES`
lines; ``tests/test_code_size.py`` asserts the same limit. Modules have no line limit: a module
is cut by job, and may be long when it is one job (the pseudorange model, a reader).

    python benchmarks/code_size.py [--top 15] [--package gnss_cli]
"""

from __future__ import annotations

import argparse
import ast
import sys
from dataclasses import dataclass
from pathlib import Path

FUNCTION_MAX_LINES = 100
PACKAGE = Path(__file__).resolve().parents[1] / "gnss_cli"


@dataclass(frozen=True, slots=True)
class Size:
    """Lines of one module or function; ``where`` is ``path`` or ``path:line name``."""

    lines: int
    where: str


def measure(package: Path = PACKAGE) -> tuple[list[Size], list[Size]]:
    """Module and function sizes under ``package``, largest first (paths relative to its parent)."""
    modules: list[Size] = []
    functions: list[Size] = []
    for path in sorted(package.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        rel = path.relative_to(package.parent).as_posix()
        modules.append(Size(len(text.splitlines()), rel))
        for node in ast.walk(ast.parse(text, filename=str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                assert node.end_lineno is not None
                functions.append(Size(node.end_lineno - node.lineno + 1, f"{rel}:{node.lineno} {node.name}"))
    def by_size(s: Size) -> tuple[int, str]:
        return (-s.lines, s.where)
    return sorted(modules, key=by_size), sorted(functions, key=by_size)


def offenders(package: Path = PACKAGE) -> list[str]:
    """One line per function over :data:`FUNCTION_MAX_LINES`."""
    _, functions = measure(package)
    return [f"function {f.where}: {f.lines} lines > {FUNCTION_MAX_LINES}" for f in functions
            if f.lines > FUNCTION_MAX_LINES]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--top", type=int, default=15, help="rows of each table (default 15)")
    parser.add_argument("--package", type=Path, default=PACKAGE, help="package folder (default gnss_cli)")
    args = parser.parse_args(argv)
    modules, functions = measure(args.package)
    print("largest modules (no limit)")
    for m in modules[: args.top]:
        print(f"{m.lines:6d}  {m.where}")
    print(f"\nlargest functions (limit {FUNCTION_MAX_LINES} lines)")
    for f in functions[: args.top]:
        print(f"{f.lines:6d}  {f.where}")
    bad = offenders(args.package)
    if bad:
        print("\nover the limits:", *bad, sep="\n  ", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
