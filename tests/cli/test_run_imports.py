"""What a whole gnss-solve run imports: the default path stays free of the heavy modules it
does not use (each costs 0.05-0.4 s of every run), and Parquet output still gets pyarrow."""

from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path

import pandas as pd

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_rinex" / "static"
UNUSED = ("dask", "pyarrow", "georinex", "matplotlib", "hatanaka", "scipy.stats", "scipy.optimize", "scipy.linalg")
"""Packages and modules a default run does not use (scipy.special computes the integrity
test's chi-square quantiles: the rest of scipy stays out)."""


_RUN = """
import os, runpy, sys
report, end = sys.argv.pop(1), os._exit
def _exit(code):  # gnss-solve ends with os._exit (no interpreter teardown): report first
    with open(report, "w") as f:
        f.write("\\n".join(sorted(n for n, m in list(sys.modules.items()) if m is not None)))
    end(code)
os._exit = _exit
runpy.run_module("gnss_cli.cli.solve", run_name="__main__")
"""


def _imported(tmp_path: Path, *args: str) -> set[str]:
    """Names of the modules (and their top-level packages) a ``gnss-solve`` process has loaded when it exits."""
    report = tmp_path / "modules.txt"
    cmd = [sys.executable, "-c", _RUN, str(report), str(SAMPLE / "obs.rnx"), str(SAMPLE / "nav.rnx"), "-q", *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    names = set(report.read_text().split())
    return names | {n.split(".")[0] for n in names}


def _pulled_in_by_scipy_special() -> set[str]:
    """The modules of UNUSED that scipy.special itself imports in this environment (scipy 1.10,
    the lowest allowed, imports scipy.linalg with it; newer versions do not): not ours to avoid."""
    code = "import sys, scipy.special; print(' '.join(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    return set(UNUSED) & set(out)


def test_default_run_imports_none_of_the_unused_heavy_modules(tmp_path: Path) -> None:
    modules = _imported(tmp_path, "-o", str(tmp_path / "positions.csv"))
    assert {"numpy", "pandas", "xarray"} <= modules  # the scan sees the imports
    unused = set(UNUSED) - _pulled_in_by_scipy_special()
    assert not modules & unused, sorted(modules & unused)
    assert pd.read_csv(tmp_path / "positions.csv")["status"].eq("ok").mean() > 0.9


def test_parquet_output_still_imports_pyarrow(tmp_path: Path) -> None:
    modules = _imported(tmp_path, "-o", str(tmp_path / "positions.parquet"))
    assert "pyarrow" in modules
    table = pd.read_parquet(tmp_path / "positions.parquet")
    assert len(table) == 121 and table["status"].eq("ok").mean() > 0.9  # the sample's 121 epochs


def test_the_process_ends_with_its_status_and_every_byte_of_stdout(tmp_path: Path) -> None:
    """gnss-solve ends without the interpreter's teardown: the CSV on stdout is complete (flushed)
    and the exit status is the run's (0; 4 for a missing file; 2 for a usage error)."""
    base = [sys.executable, "-m", "gnss_cli.cli.solve"]
    ok = subprocess.run([*base, str(SAMPLE / "obs.rnx"), str(SAMPLE / "nav.rnx"), "-q"], capture_output=True, text=True,
                        cwd=tmp_path, check=False)
    assert ok.returncode == 0 and ok.stdout.endswith("\n")
    table = pd.read_csv(io.StringIO(ok.stdout))
    assert len(table) == 121 and table["status"].eq("ok").all()
    missing = subprocess.run([*base, str(tmp_path / "none.rnx"), str(SAMPLE / "nav.rnx")], capture_output=True, text=True,
                             cwd=tmp_path, check=False)
    assert missing.returncode == 4 and "none.rnx" in missing.stderr
    usage = subprocess.run([*base, str(SAMPLE / "obs.rnx")], capture_output=True, text=True, cwd=tmp_path, check=False)
    assert usage.returncode == 2 and missing.stdout == usage.stdout == ""
