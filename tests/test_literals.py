"""No pasted tables of computed numbers in the package: a value a library computes is computed.

Float literals of 15 or more significant digits (``10.827566170662733``) are what a computed
value looks like when it is printed and pasted; physical and defining constants are written
with the digits their documents give (WGS-84's ``298.257223563``: 12). At most
:data:`MAX_LONG_FLOATS` of them may appear under ``gnss_cli/``.
"""

from __future__ import annotations

import io
import tokenize
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "gnss_cli"
MAX_LONG_FLOATS = 10
LONG_DIGITS = 15


def significant_digits(literal: str) -> int:
    """Significant digits of a float literal (0 for integers): from the first nonzero digit of
    the mantissa to its last nonzero one.

    >>> [significant_digits(s) for s in ("10.827566170662733", "0.00120", "6.69437999014e-3", "1_000.5", "42", "0x1F")]
    [17, 2, 12, 5, 0, 0]
    """
    text = literal.lower().replace("_", "").rstrip("j")
    if text.startswith(("0x", "0o", "0b")) or not ("." in text or "e" in text):
        return 0
    return len(text.split("e")[0].replace(".", "").strip("0"))


def long_floats(source: str) -> list[tuple[int, str]]:
    """``(line, literal)`` of the float literals of ``source`` with at least :data:`LONG_DIGITS`
    significant digits."""
    tokens = tokenize.generate_tokens(io.StringIO(source).readline)
    return [(tok.start[0], tok.string) for tok in tokens
            if tok.type == tokenize.NUMBER and significant_digits(tok.string) >= LONG_DIGITS]


def test_the_package_has_no_pasted_table_of_long_floats() -> None:
    found = [f"{path.relative_to(PACKAGE.parent)}:{line}: {literal}"
             for path in sorted(PACKAGE.rglob("*.py")) for line, literal in long_floats(path.read_text(encoding="utf-8"))]
    assert len(found) <= MAX_LONG_FLOATS, f"{len(found)} float literals of {LONG_DIGITS}+ digits: {found[:20]}"


def test_long_floats_are_found() -> None:
    source = "X = (10.827566170662733, 13.815510557964274)\nY = 298.257223563  # 12 digits\nZ = 1e-3\n"
    assert long_floats(source) == [(1, "10.827566170662733"), (1, "13.815510557964274")]
