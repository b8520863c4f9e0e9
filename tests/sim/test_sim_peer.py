"""Independent checks of simulated data: rnx2rtkp and gnss-solve reproduce the truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sim_datasets import errors_against_truth, rnx2rtkp_positions, run_solve, simulate

# rnx2rtkp prints positions to 0.1 mm and obs are written to 1 mm: the 5 cm bound of the issue
# leaves room only for modelling differences, which must be absent.
PEER_TOL_M = 0.05


@pytest.mark.parametrize(("fixture", "navsys"), [("static_exact_gps", 1), ("static_exact_gps_gal", 9)])
def test_rnx2rtkp_reproduces_truth_on_noise_free_static_set(
    fixture: str, navsys: int, request: pytest.FixtureRequest, tmp_path: Path
) -> None:
    data: Path = request.getfixturevalue(fixture)
    pos = rnx2rtkp_positions(tmp_path, data / "obs.rnx", data / "nav.rnx", navsys)
    n_epochs = len(pd.read_csv(data / "truth.csv"))
    assert len(pos) == n_epochs
    err = errors_against_truth(pos, data / "truth.csv")
    assert err.max() < PEER_TOL_M, f"max 3-D error {err.max():.4f} m"


def test_rnx2rtkp_reproduces_truth_on_flight(flight_exact: Path, tmp_path: Path) -> None:
    """The moving receiver's truth is the antenna at the true reception time."""
    pos = rnx2rtkp_positions(tmp_path, flight_exact / "obs.rnx", flight_exact / "nav.rnx", 9)
    assert len(pos) == len(pd.read_csv(flight_exact / "truth.csv"))
    assert errors_against_truth(pos, flight_exact / "truth.csv").max() < PEER_TOL_M


def test_rnx2rtkp_reads_rinex2_output(tmp_path: Path) -> None:
    data = simulate(tmp_path / "v2", systems=("G",), duration_s=300.0, interval_s=10.0, errors="clock", rinex_version="2.11")
    assert (data / "obs.rnx").read_text().startswith("     2.11           OBSERVATION DATA")
    pos = rnx2rtkp_positions(tmp_path, data / "obs.rnx", data / "nav.rnx", 1)
    assert len(pos) == 31
    assert errors_against_truth(pos, data / "truth.csv").max() < PEER_TOL_M


def test_rnx2rtkp_reproduces_truth_with_beidou(tmp_path: Path) -> None:
    """BeiDou records are written in BDT with the BDT-week node longitude: a reader that
    converts them as RINEX says recovers the same orbits."""
    data = simulate(tmp_path / "c", systems=("C",), duration_s=600.0, interval_s=30.0, errors="none")
    pos = rnx2rtkp_positions(tmp_path, data / "obs.rnx", data / "nav.rnx", 32)
    assert len(pos) == 21
    assert errors_against_truth(pos, data / "truth.csv").max() < PEER_TOL_M


def test_gnss_solve_within_1cm_on_noise_free_gps_set(static_exact_gps: Path, tmp_path: Path) -> None:
    out = tmp_path / "sol.csv"
    res = run_solve(
        [
            str(static_exact_gps / "obs.rnx"),
            str(static_exact_gps / "nav.rnx"),
            "--method", "ls", "--iono", "none", "--tropo", "none",
            "--reference-csv", str(static_exact_gps / "truth.csv"),
            "-q", "-o", str(out),
        ]
    )
    if res.returncode != 0 and "--reference-csv" in res.stderr:
        pytest.skip("gnss-solve has no --reference-csv yet")
    assert res.returncode == 0, res.stderr
    sol = pd.read_csv(out)
    assert len(sol) == len(pd.read_csv(static_exact_gps / "truth.csv"))
    assert (sol["status"] == "ok").all()
    assert sol["err_3d_m"].max() < 0.01


def test_ls_errors_consistent_with_noise_and_pdop(tmp_path: Path) -> None:
    """White constant-sigma noise only: E|error|^2 = sigma^2 PDOP^2 for LS.

    2,880 independent epochs give the ratio to ~1.5 % (one sigma): [0.8, 1.25] fails only for
    a wrong noise level, wrong weights or an error source that should be off.
    """
    sigma = 1.5
    data = simulate(
        tmp_path / "noise",
        systems=("G",),
        duration_s=2879.0 * 30.0,
        interval_s=30.0,
        errors="noise",
        error_settings={"noise_sigma_m": sigma, "noise_elevation_dependent": False},
    )
    out = tmp_path / "sol.csv"
    res = run_solve(
        [
            str(data / "obs.rnx"), str(data / "nav.rnx"),
            "--method", "ls", "--iono", "none", "--tropo", "none", "--elevation-mask", "5",
            "--reference-csv", str(data / "truth.csv"), "-q", "-o", str(out),
        ]
    )
    if res.returncode != 0 and "--reference-csv" in res.stderr:
        pytest.skip("gnss-solve has no --reference-csv yet")
    assert res.returncode == 0, res.stderr
    sol = pd.read_csv(out)
    sol = sol[sol["status"] == "ok"]
    assert len(sol) == 2880
    ratio = np.mean(sol["err_3d_m"] ** 2) / np.mean(sigma**2 * sol["pdop"] ** 2)
    assert 0.8 <= ratio <= 1.25, ratio
