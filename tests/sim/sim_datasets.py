"""Simulated data sets and peer runs shared by the simulator tests."""

from __future__ import annotations

import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gnss_cli.sim.error_sources import parse_error_list
from gnss_cli.sim.scenario import ScenarioConfig, run_scenario, write_scenario

PEER_CONF = Path(__file__).resolve().parents[3] / "shared" / "peer" / "rnx2rtkp-spp.conf"


def simulate(out_dir: Path, **changes: object) -> Path:
    """Run the simulator with ``changes`` over the defaults; ``errors`` takes the CLI's words."""
    errors = str(changes.pop("errors", "none"))
    error_changes = changes.pop("error_settings", {})
    base = ScenarioConfig()
    cfg = replace(base, **changes)  # type: ignore[arg-type]
    cfg = replace(cfg, errors=replace(cfg.errors.with_sources(parse_error_list(errors)), **error_changes))  # type: ignore[arg-type]
    write_scenario(run_scenario(cfg), out_dir)
    return out_dir


def rnx2rtkp_positions(tmp: Path, obs: Path, nav: Path, navsys: int) -> np.ndarray:
    """rnx2rtkp single-point solutions (tow, x, y, z) with iono and tropo corrections off."""
    exe = shutil.which("rnx2rtkp")
    if exe is None:
        pytest.skip("rnx2rtkp (Debian package rtklib) is not on PATH")
    text = PEER_CONF.read_text() if PEER_CONF.is_file() else ""
    if not text:
        pytest.skip(f"peer settings {PEER_CONF} not found")
    lines = []
    for line in text.splitlines():
        key = line.split("=")[0].strip()
        if key == "pos1-ionoopt":
            line = "pos1-ionoopt       =off"
        elif key == "pos1-tropopt":
            line = "pos1-tropopt       =off"
        elif key == "pos1-navsys":
            line = f"pos1-navsys        ={navsys}"
        lines.append(line)
    conf = tmp / f"spp_{navsys}.conf"
    conf.write_text("\n".join(lines) + "\n")
    out = tmp / f"out_{navsys}_{obs.parent.name}.pos"
    subprocess.run([exe, "-k", str(conf), "-p", "0", "-e", "-o", str(out), str(obs), str(nav)], check=True, capture_output=True)
    return np.loadtxt(out, comments="%", usecols=(1, 2, 3, 4), ndmin=2)


def errors_against_truth(pos: np.ndarray, truth_csv: Path) -> np.ndarray:
    """3-D distance of each (tow, x, y, z) row from the truth epoch nearest in time."""
    truth = pd.read_csv(truth_csv)
    tow = truth["tow_s"].to_numpy()
    i = np.abs(pos[:, :1] - tow[None, :]).argmin(axis=1)
    assert np.all(np.abs(tow[i] - pos[:, 0]) < 0.01), "solution epochs do not match truth epochs"
    return np.linalg.norm(pos[:, 1:4] - truth[["x_m", "y_m", "z_m"]].to_numpy()[i], axis=1)


def run_solve(args: list[str]) -> subprocess.CompletedProcess[str]:
    """gnss-solve as a subprocess (the package from the working tree)."""
    root = Path(__file__).resolve().parents[2]
    return subprocess.run([sys.executable, "-W", "ignore", "-m", "gnss_cli.cli.solve", *args], cwd=root, capture_output=True, text=True)
