"""Print a pip constraints file that pins every dependency to its declared lower bound.

Reads ``pyproject.toml`` (``[project] dependencies`` and every optional extra, or only the
extras named on the command line) and prints ``name==X`` for each ``name>=X`` requirement
whose environment marker holds for this interpreter. With these constraints,
``pip install -c FILE -e '.[test]'`` installs the oldest versions that ``pyproject.toml``
claims to support, so CI can check that the lower bounds are true.

Usage: python .ci/lowest_constraints.py [pyproject.toml] [--extra NAME ...] > constraints.txt
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import tomllib

_REQUIREMENT = re.compile(
    r"""^\s*(?P<name>[A-Za-z0-9][A-Za-z0-9._-]*)\s*(?:\[[^\]]*\])?\s*(?P<spec>[^;]*?)\s*(?:;\s*(?P<marker>.+))?$"""
)


def _marker_holds(marker: str | None) -> bool:
    if not marker:
        return True
    try:
        from packaging.markers import Marker
    except ImportError:  # pip vendors packaging
        from pip._vendor.packaging.markers import Marker
    return Marker(marker).evaluate()


def lower_bounds(requirements: list[str]) -> list[tuple[str, str]]:
    """``(name, version)`` for each requirement with a ``>=`` bound whose marker holds here."""
    out = []
    for text in requirements:
        m = _REQUIREMENT.match(text)
        if m is None:
            raise SystemExit(f"lowest_constraints: cannot parse requirement {text!r}")
        if not _marker_holds(m["marker"]):
            continue
        bounds = [s.strip()[2:].strip() for s in m["spec"].split(",") if s.strip().startswith(">=")]
        if bounds:
            out.append((m["name"], bounds[0]))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pyproject", nargs="?", default="pyproject.toml", type=Path)
    parser.add_argument("--extra", action="append", help="optional extras to include (default: all)")
    args = parser.parse_args(argv)
    project = tomllib.loads(args.pyproject.read_text(encoding="utf-8"))["project"]
    requirements = list(project.get("dependencies", []))
    extras = project.get("optional-dependencies", {})
    for name in args.extra or sorted(extras):
        if name not in extras:
            raise SystemExit(f"lowest_constraints: no extra {name!r} in {args.pyproject}")
        requirements += extras[name]
    pins = list(dict.fromkeys(lower_bounds(requirements)))  # an extra may repeat another's pin
    if not pins:
        raise SystemExit(f"lowest_constraints: no '>=' bounds found in {args.pyproject}")
    print(f"# lowest versions allowed by {args.pyproject.name} (written by .ci/lowest_constraints.py)")
    for name, version in pins:
        print(f"{name}=={version}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
