"""The test run's summary lists skipped tests once per reason (tests/conftest.py with the
``addopts`` of pyproject.toml), as a user of the README's ``python -m pytest -q`` sees it: a tiny
test folder with this conftest and these options, run by pytest in its own process."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

TESTS = Path(__file__).resolve().parent
ADDOPTS = tomllib.loads((TESTS.parent / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]["addopts"]

TINY = "import pytest\n" + "".join(
    f"\ndef test_needs_real_data_{i}(rinex_dir):  # the conftest's fixture, its real-data folder missing\n    pass\n"
    for i in range(5)) + '''

@pytest.mark.parametrize("i", range(3))
def test_needs_a_tool(i):
    pytest.skip("pyrtklib is not installed")

@pytest.mark.skipif(True, reason="only on Windows")
def test_marked():
    pass

def test_passes():
    pass

def test_fails():
    assert 1 == 2
'''


def _run(folder: Path, *args: str) -> str:
    missing = "\nRINEX = Path(__file__).parent / 'shared' / 'rinex'  # (no real data here)\n"
    (folder / "conftest.py").write_text((TESTS / "conftest.py").read_text() + missing)
    (folder / "test_tiny.py").write_text(TINY)
    (folder / "pyproject.toml").write_text(f"[tool.pytest.ini_options]\naddopts = {json.dumps(ADDOPTS)}\n")
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args], cwd=folder,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1, proc.stdout + proc.stderr  # the one failing test
    return proc.stdout


def test_skips_are_summarised_once_per_reason(tmp_path: Path) -> None:
    out = _run(tmp_path)
    skipped = [line for line in out.splitlines() if "SKIPPED" in line]
    assert len(skipped) == 3, out
    assert re.search(r"^SKIPPED \[5\] real RINEX data folder .*rinex is missing", out, re.M), out
    assert "SKIPPED [3] pyrtklib is not installed" in skipped and "SKIPPED [1] only on Windows" in skipped, out
    assert skipped[0].startswith("SKIPPED [5]")  # the commonest reason first
    assert re.search(r"^FAILED test_tiny.py::test_fails", out, re.M), out  # failures keep their line
    assert "9 skipped" in out and "1 failed" in out and "1 passed" in out


def test_asking_for_skips_gives_pytests_own_lines(tmp_path: Path) -> None:
    out = _run(tmp_path, "-ra")
    # pytest's own lines: one per test (pytest 8) or per skip location (pytest 7: the fixture's line, counted)
    counts = re.findall(r"^SKIPPED \[(\d+)\] \S+: real RINEX data folder", out, re.M)
    assert sum(int(n) for n in counts) == 5, out
    assert "skipped, by reason" not in out
