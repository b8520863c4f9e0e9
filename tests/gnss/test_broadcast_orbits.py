"""GPS broadcast orbits and clocks against precise orbits (CODE final SP3), Kepler, velocity."""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.constants import C_M_S
from gnss_cli.gnss.ephemeris import KeplerEphemeris, select_ephemeris
from gnss_cli.gnss.orbits import broadcast_states, solve_kepler
from gnss_cli.gnss.time import datetime2gps_s
from gnss_cli.io.rinex import read_nav


@pytest.fixture(scope="module")
def sp3_comparison(rinex_dir):
    import georinex

    folder = rinex_dir / "orbits-2021-118"
    eph = KeplerEphemeris.from_dataset(read_nav(folder / "brdc1180.21n"))
    sp3 = georinex.load_sp3(folder / "COD0MGXFIN_20211180000_01D_05M_ORB.SP3", None)
    svs = np.array([s for s in sp3.sv.values.astype(str) if s.startswith("G")])
    sp3 = sp3.sel(sv=svs)
    t = datetime2gps_s(sp3.time.values)
    idx = select_ephemeris(eph, svs, t)
    states = broadcast_states(eph, idx, t[:, None])
    precise = sp3.position.values * 1e3  # km -> m
    clock = sp3.clock.values
    clock = np.where(np.abs(clock) >= 999999.0, np.nan, clock) * 1e-6  # us -> s; 999999.999999 = bad
    return states, precise, clock


def test_broadcast_positions_match_precise_orbits(sp3_comparison):
    states, precise, _ = sp3_comparison
    diff = states.pos_ecef_m - precise
    err = np.linalg.norm(diff, axis=-1)
    ok = np.isfinite(err)
    assert ok.sum() > 2000  # all GPS satellites over 6 h at 5 min
    rms = np.sqrt(np.mean(err[ok] ** 2))
    assert rms <= 2.5, rms
    assert err[ok].max() <= 7.0, err[ok].max()
    # The broadcast orbit refers to the antenna phase centre: a negative radial mean of ~1 m.
    radial = np.sum(diff * precise / np.linalg.norm(precise, axis=-1, keepdims=True), axis=-1)
    assert -2.0 < np.nanmean(radial) < -0.3


def test_broadcast_clock_polynomial_matches_precise_clocks(sp3_comparison):
    states, _, clock = sp3_comparison
    # SP3 clocks exclude the periodic relativistic term: compare the polynomial only.
    d = (states.clock_s - states.relativistic_s - clock) * C_M_S
    d = d[np.isfinite(d).any(axis=1)]
    d = d - np.nanmean(d, axis=1, keepdims=True)  # remove the common (reference clock) part
    assert np.isfinite(d).sum() > 2000
    assert np.sqrt(np.nanmean(d**2)) <= 1.0


def test_kepler_solution_satisfies_equation_at_high_eccentricity():
    rng = np.random.default_rng(1)
    m = rng.uniform(-np.pi, np.pi, 1000)
    e = rng.uniform(0.0, 0.9, 1000)
    ea = solve_kepler(m, e)
    assert np.max(np.abs(ea - e * np.sin(ea) - m)) < 1e-12


def test_velocity_is_derivative_of_position(rinex_dir):
    eph = KeplerEphemeris.from_dataset(read_nav(rinex_dir / "rtklib-0759" / "07590920.05n"))
    sv = np.unique(eph.sv)
    t = eph.toe_gps_s.min() + np.arange(0.0, 7200.0, 600.0)
    idx = select_ephemeris(eph, sv, t)
    s0 = broadcast_states(eph, idx, t[:, None])
    sp = broadcast_states(eph, idx, t[:, None] + 0.5)
    sm = broadcast_states(eph, idx, t[:, None] - 0.5)
    fd = sp.pos_ecef_m - sm.pos_ecef_m
    ok = np.isfinite(fd).all(axis=-1)
    assert ok.sum() > 50
    assert np.max(np.abs(fd[ok] - s0.vel_ecef_m_s[ok])) < 1e-3  # m/s


def test_selection_respects_fit_interval_and_health(rinex_dir):
    eph = KeplerEphemeris.from_dataset(read_nav(rinex_dir / "rtklib-0759" / "07590920.05n"))
    sv = np.array([eph.sv[0]])
    far = np.array([eph.toe_gps_s.max() + 3 * 86400.0])
    assert select_ephemeris(eph, sv, far)[0, 0] == -1
    t = np.array([eph.toe_gps_s[0]])
    k = select_ephemeris(eph, sv, t)[0, 0]
    assert k >= 0 and eph.sv[k] == sv[0] and abs(eph.toe_gps_s[k] - t[0]) <= 2 * 3600
    sick = KeplerEphemeris(**{**{f: getattr(eph, f) for f in eph.__dataclass_fields__}, "health": np.ones(len(eph))})
    assert select_ephemeris(sick, sv, t)[0, 0] == -1
