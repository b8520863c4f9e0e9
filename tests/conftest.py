"""Shared fixtures: the real-data folder beside the repository and the RTKLIB peer; the skipped
tests summarised as one line per reason."""

from __future__ import annotations

import shutil
from collections import Counter
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = (REPO / ".." / "shared").resolve()
RINEX = SHARED / "rinex"
PEER_CONF = SHARED / "peer" / "rnx2rtkp-spp.conf"


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """With ``--doctest-modules`` (pyproject addopts) pytest would also import conftest.py and
    helper modules of tests/ as doctest modules, a second time under other names; only the
    test_*.py files are collected here (the helpers and conftests still load as usual)."""
    if collection_path.suffix == ".py" and not collection_path.name.startswith("test_"):
        return True
    return None


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """The skipped tests, one line per distinct reason with its count (``SKIPPED [141] real RINEX
    data folder ... is missing``), instead of pytest's line per test: pyproject's ``addopts``
    leaves ``s`` out of ``-r`` (``-rfExX``: failures, errors, xfails and xpasses still get a line
    each). A run that asks for skips itself (``-rs``, ``-ra``) gets pytest's own lines instead."""
    if "s" in getattr(terminalreporter, "reportchars", "s") or getattr(terminalreporter, "no_summary", False):
        return
    reasons: Counter[str] = Counter()
    for report in terminalreporter.stats.get("skipped", []):
        longrepr = report.longrepr
        reason = longrepr[2] if isinstance(longrepr, tuple) and len(longrepr) == 3 else str(longrepr)
        reasons[reason.removeprefix("Skipped: ")] += 1
    if reasons:
        terminalreporter.write_sep("=", "skipped, by reason")
        for reason, count in reasons.most_common():
            terminalreporter.write_line(f"SKIPPED [{count}] {reason}")


@pytest.fixture(scope="session")
def rinex_dir() -> Path:
    """``../shared/rinex``; tests that need it are skipped when it is missing."""
    if not RINEX.is_dir():
        pytest.skip(f"real RINEX data folder {RINEX} is missing (it sits beside the repository in CI)")
    return RINEX


@pytest.fixture(scope="session")
def rnx2rtkp() -> str:
    """Path of RTKLIB's rnx2rtkp (Debian package rtklib); skip when it is not installed."""
    exe = shutil.which("rnx2rtkp")
    if exe is None:
        pytest.skip("rnx2rtkp not on PATH (apt-get install -y rtklib)")
    if not PEER_CONF.is_file():
        pytest.skip(f"peer configuration {PEER_CONF} is missing")
    return exe


def run_rnx2rtkp(exe: str, obs: Path, navs: list[Path], workdir: Path, **options: str):
    """Run rnx2rtkp single point on plain copies; return (tow_s (k,), xyz_m (k, 3)).

    ``options`` override keys of the peer configuration (e.g. ``pos1_navsys="9"``,
    ``pos1_ionoopt="off"``); compressed inputs must already be decompressed.
    """
    import subprocess

    import numpy as np

    conf_lines = []
    for line in PEER_CONF.read_text().splitlines():
        key = line.split("=")[0].strip()
        if key.replace("-", "_") in options:
            line = f"{key:<19}={options[key.replace('-', '_')]}"
        conf_lines.append(line)
    conf = workdir / "peer.conf"
    conf.write_text("\n".join(conf_lines) + "\n")
    local = []
    for p in [obs, *navs]:
        target = workdir / Path(p).name
        if not target.exists():
            shutil.copy(p, target)
        local.append(str(target))
    out = workdir / "peer.pos"
    subprocess.run([exe, "-k", str(conf), "-p", "0", "-e", "-o", str(out), *local],
                   check=True, capture_output=True, timeout=600)
    rows = [line.split() for line in out.read_text().splitlines() if line.strip() and not line.startswith("%")]
    tow = np.array([float(r[1]) for r in rows])
    xyz = np.array([[float(v) for v in r[2:5]] for r in rows])
    return tow, xyz


@pytest.fixture(scope="session")
def peer():
    """The rnx2rtkp runner (see :func:`run_rnx2rtkp`), skipping when rtklib is missing."""
    exe = shutil.which("rnx2rtkp")
    if exe is None:
        pytest.skip("rnx2rtkp not on PATH (apt-get install -y rtklib)")
    if not PEER_CONF.is_file():
        pytest.skip(f"peer configuration {PEER_CONF} is missing")

    def _run(obs: Path, navs: list[Path], workdir: Path, **options: str):
        return run_rnx2rtkp(exe, obs, navs, workdir, **options)

    return _run
