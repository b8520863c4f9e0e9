"""QZSS on the GPS receiver clock (the default) or on its own (``qzss_own_clock``).

A simulated static receiver in Tokyo sees GPS and the simulated QZSS (three quasi-zenith
satellites on one figure-eight ground track over Japan and one GEO), all on one receiver
clock as in the real systems (QZSS time is steered to GPS time). Expected values come from
the least-squares identities, not from earlier runs: adding rows to a least-squares problem
never raises a DOP, adding an unknown never lowers one, and a single satellite that brings its
own clock unknown adds nothing to the position.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gnss_cli.config import load_config
from gnss_cli.constants import C_M_S, OMEGA_E_RAD_S
from gnss_cli.pipeline import EpochStatus, RunResult, load_epochs, solve_method
from gnss_cli.report import positions_table
from gnss_cli.sim.error_sources import parse_error_list
from gnss_cli.sim.scenario import ScenarioConfig, run_scenario, write_scenario

TOKYO = (35.7, 139.7, 40.0)


@pytest.fixture(scope="module")
def japan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """1 h at 60 s, static in Tokyo, GPS + QZSS, the receiver clock the only error (modelled exactly)."""
    base = ScenarioConfig()
    cfg = replace(base, systems=("G", "J"), duration_s=3600.0, interval_s=60.0,
                  latitude_deg=TOKYO[0], longitude_deg=TOKYO[1], height_m=TOKYO[2],
                  errors=base.errors.with_sources(parse_error_list("clock")))
    out = tmp_path_factory.mktemp("japan_gj")
    write_scenario(run_scenario(cfg), out)
    return out


def _solve(d: Path, method: str = "wls", **overrides: object):
    cfg = load_config(overrides={"methods": method, "iono": "none", "tropo": "none", **overrides})
    data = load_epochs(d / "obs.rnx", [d / "nav.rnx"], cfg)
    return data, solve_method(data, method, cfg)


def _qzss_used(data, sol) -> np.ndarray:
    """QZSS satellites used per epoch (usable and not excluded; the mask keeps all here)."""
    j = np.char.startswith(data.sv, "J")
    return np.isfinite(sol.residuals_m[:, j]).sum(axis=1)


def test_qzss_shares_the_gps_clock_and_lowers_pdop(japan):
    gps_data, gps = _solve(japan, systems=["G"])
    data, gj = _solve(japan)
    assert data.systems == ("G",)  # one clock column: QZSS satellites are in GPS's
    assert (gj.status == EpochStatus.OK).all() and (gps.status == EpochStatus.OK).all()
    n_j = _qzss_used(data, gj)
    assert n_j.min() >= 2  # QZSS is high over Japan: two or more all the time
    assert (gj.n_sat == gps.n_sat + n_j).all()
    assert (gj.pdop < gps.pdop - 0.1).all(), (gps.pdop, gj.pdop)
    table = positions_table(RunResult(data, {"wls": gj}))
    assert not [c for c in table.columns if c.startswith("tdop_")]  # one clock: the tdop column only
    # the fix is the truth (only the receiver clock is simulated, and it is estimated) to the
    # RINEX rounding of the pseudoranges (1 mm) times the PDOP
    truth = pd.read_csv(japan / "truth.csv")[["x_m", "y_m", "z_m"]].to_numpy()
    assert np.abs(gj.x_ecef_m - truth).max() < 1e-2


def test_own_clock_gives_tdop_j_and_takes_part_of_the_gain(japan):
    """With its own clock, n QZSS satellites add n - 1 between-satellite differences: their
    gain shrinks (all of it with one satellite, below), by a fifth with the four here."""
    _, gps = _solve(japan, systems=["G"])
    _, shared = _solve(japan)
    data, own = _solve(japan, qzss_own_clock=True)
    assert data.systems == ("G", "J")
    table = positions_table(RunResult(data, {"wls": own}))
    assert [c for c in table.columns if c.startswith("tdop_")] == ["tdop_G", "tdop_J"]
    assert np.isfinite(table["tdop_J"]).all()
    # rows never raise a DOP, an unknown never lowers one
    assert (own.pdop <= gps.pdop + 1e-9).all() and (shared.pdop <= own.pdop + 1e-9).all()
    gain_shared, gain_own = (gps.pdop - shared.pdop).mean(), (gps.pdop - own.pdop).mean()
    assert gain_own < 0.85 * gain_shared, (gain_own, gain_shared)


def test_one_qzss_satellite_on_its_own_clock_adds_nothing(japan):
    """One satellite with its own clock unknown only estimates that clock: PDOP is GPS's."""
    _, gps = _solve(japan, systems=["G"])
    only_j07 = ["J01", "J02", "J03"]
    _, own = _solve(japan, qzss_own_clock=True, exclude=only_j07)
    _, shared = _solve(japan, exclude=only_j07)
    np.testing.assert_allclose(own.pdop, gps.pdop, rtol=1e-9)
    np.testing.assert_allclose(own.x_ecef_m, gps.x_ecef_m, atol=1e-6)
    assert (shared.pdop < gps.pdop).all()


def test_qzss_alone_is_the_reference_clock(japan):
    data, sol = _solve(japan, systems=["J"], max_gdop=1e3)
    assert data.systems == ("J",)
    assert (sol.n_sat == 4).all() and (sol.status == EpochStatus.UNTESTED).all()  # four satellites: nothing to test
    truth = pd.read_csv(japan / "truth.csv")[["x_m", "y_m", "z_m"]].to_numpy()
    assert np.abs(sol.x_ecef_m - truth).max() < 1e-2 * sol.pdop.max()  # 1 mm RINEX rounding times PDOP


def test_shared_clock_fix_equals_an_independent_stacked_least_squares(japan):
    """Gauss-Newton on ``P_i = |s_i - u| + sagnac_i + b`` with one clock for G and J, solved
    with numpy's lstsq from the satellite states and corrected pseudoranges of the range model."""
    data, sol = _solve(japan, method="ls", **{"weights.model": "equal"}, integrity="off", elevation_mask_deg=0.0)
    gj = np.char.startswith(data.sv, "G") | np.char.startswith(data.sv, "J")
    for t in range(data.time_gps_s.size):
        use = data.usable[t] & gj
        s, p = data.sat_ecef_m[t, use], data.pr_corrected_m[t, use]
        assert np.char.startswith(data.sv[use], "J").sum() >= 2
        x = np.zeros(4)
        for _ in range(20):
            d = s - x[:3]
            rho = np.linalg.norm(d, axis=1) + OMEGA_E_RAD_S / C_M_S * (s[:, 0] * x[1] - s[:, 1] * x[0])
            A = np.column_stack([-d / np.linalg.norm(d, axis=1)[:, None], np.ones(len(p))])
            dx = np.linalg.lstsq(A, p - rho - x[3], rcond=None)[0]
            x += dx
            if np.linalg.norm(dx[:3]) < 1e-9:
                break
        np.testing.assert_allclose(sol.x_ecef_m[t], x[:3], rtol=0, atol=1e-6)
        assert sol.clock_m[t] == pytest.approx(x[3], abs=1e-6)
