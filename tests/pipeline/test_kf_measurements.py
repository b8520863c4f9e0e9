"""What the kf is given (``measurements``): pseudoranges, range rates and time-differenced carrier
phase, with the smoother's variance factors and gate.

The simulator writes no carrier phase, so the phase is made as in ``test_phase_rows.py``: from a
noise-free flight of the same seed (same orbits, trajectory and receiver clock) its corrected
pseudorange, the exact range plus clock, plus a constant per satellite (the unknown ambiguity).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gnss_cli.config import load_config
from gnss_cli.errors import ConfigError
from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic
from gnss_cli.gnss.carrier import phase_slips
from gnss_cli.io.reference import reference_from_csv, reference_from_pos
from gnss_cli.pipeline import load_epochs, solve_method
from gnss_cli.pipeline.measurements import factors_from_totals, free_misfit_totals
from gnss_cli.pipeline.kalman import run_kalman
from gnss_cli.pipeline.kalman_rows import gate_threshold, measurement_kinds, variance_factors
from gnss_cli.pipeline.results import EpochData

from flight_scenarios import simulate_flight

BASE = {"methods": "wls,kf", "iono": "none", "tropo": "none"}
L1_M = 299792458.0 / 1575.42e6
ALL = frozenset({"pseudorange", "doppler", "phase"})
PR_DOPPLER = frozenset({"pseudorange", "doppler"})


def _rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(v**2)))


@pytest.fixture(scope="module")
def flights(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    cfg = load_config(None, BASE)
    out: dict[str, object] = {"cfg": cfg}
    for errors in ("none", "noise"):
        d = simulate_flight(tmp_path_factory.mktemp(errors), errors)
        data = load_epochs(d / "obs.rnx", [d / "nav.rnx"], cfg)
        assert data.phase_m is None and data.range_rate_m_s is not None
        out[errors] = data
        out["ref"] = reference_from_csv(d / "truth.csv", data.time_gps_s)
    exact = out["none"]
    assert isinstance(exact, EpochData)
    out["phase"] = exact.pr_corrected_m + L1_M * np.random.default_rng(5).integers(-10**6, 10**6, exact.sv.size)
    return out


def _with_phase(data: EpochData, phase: np.ndarray, cfg) -> EpochData:  # type: ignore[no-untyped-def]
    slip = phase_slips(data.time_gps_s, phase, data.range_rate_m_s, np.zeros(phase.shape), cfg.phase_slip_m)
    return replace(data, phase_m=np.where(data.usable, phase, np.nan), phase_slip=slip)


def _displacement_error(x: np.ndarray, ref: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.diff(x, axis=0) - np.diff(ref, axis=0), axis=1)


def test_phase_changes_nothing_on_a_file_without_phase(flights) -> None:  # type: ignore[no-untyped-def]
    cfg, data = flights["cfg"], flights["noise"]
    wls = solve_method(data, "wls", cfg)
    assert measurement_kinds(data, cfg, ALL) == PR_DOPPLER
    # to 1 um, not bit for bit: one run of the lowest-versions environment differed by 1e-15
    # relative (9e-10 m) in 139 of 903 coordinates, the order of a floating-point sum; a phase row
    # used would move the track by millimetres at least
    np.testing.assert_allclose(run_kalman(data, wls, cfg, measurements=ALL).x_ecef_m,
                               run_kalman(data, wls, cfg, measurements=PR_DOPPLER).x_ecef_m, rtol=0.0, atol=1e-6)


def test_phase_rows_improve_the_kf_on_the_yamatogawa_walk(rinex_dir) -> None:  # type: ignore[no-untyped-def]
    """Measured (cv): 3D RMS 2.81 -> 2.43 m, horizontal 0.92 -> 0.30 m against the RTK trajectory
    (the smoother with phase: 2.48 and 0.36 m)."""
    d = rinex_dir / "yamatogawa-2010006-kinematic"
    cfg = load_config(None, {"methods": "wls,kf"})  # kf with every measurement: the phase is read
    data = load_epochs(d / "yamatogawa_rover.obs", [d / "brdc0060.10n"], cfg)
    assert data.phase_m is not None
    wls = solve_method(data, "wls", cfg)
    ref = reference_from_pos(d / "rtk_ref_rover.pos", data.time_gps_s, np.zeros_like(data.time_gps_s))
    lat, lon, _ = ecef2geodetic(ref)
    rms3, rmsh = {}, {}
    for kinds in (PR_DOPPLER, ALL):
        enu = np.einsum("tij,tj->ti", ecef2enu_rotation(lat, lon), run_kalman(data, wls, cfg, measurements=kinds).x_ecef_m - ref)
        rms3[kinds], rmsh[kinds] = _rms(np.linalg.norm(enu, axis=1)), _rms(np.linalg.norm(enu[:, :2], axis=1))
    assert rms3[ALL] < 0.95 * rms3[PR_DOPPLER] and rmsh[ALL] < 0.5 * rmsh[PR_DOPPLER]


def test_pseudorange_only_uses_neither_range_rates_nor_phase(flights) -> None:  # type: ignore[no-untyped-def]
    cfg = flights["cfg"]
    data = _with_phase(flights["noise"], flights["phase"], cfg)
    wls = solve_method(data, "wls", cfg)
    factors = variance_factors(data, wls, cfg)
    bare = replace(data, range_rate_m_s=None, sat_vel_ecef_m_s=None, sat_clock_drift_s_s=None, phase_m=None,
                   phase_slip=None)
    only = run_kalman(data, wls, cfg, measurements=frozenset({"pseudorange"}), factors=factors)
    alone = run_kalman(bare, wls, cfg, measurements=frozenset({"pseudorange"}), factors=factors)
    np.testing.assert_allclose(only.x_ecef_m, alone.x_ecef_m, rtol=0, atol=1e-9)
    assert np.abs(only.x_ecef_m - run_kalman(data, wls, cfg, measurements=PR_DOPPLER, factors=factors).x_ecef_m).max() > 0.1
    # a file without range rates: the pseudoranges' factor from their own misfit, the smoother's value
    assert variance_factors(bare, wls, cfg) == pytest.approx((factors[0], 1.0, 1.0), rel=1e-9)


def test_variance_factors_are_the_smoothers(flights) -> None:  # type: ignore[no-untyped-def]
    cfg = flights["cfg"]
    data = _with_phase(flights["noise"], flights["phase"], cfg)
    wls = solve_method(data, "wls", cfg)
    factors = variance_factors(data, wls, cfg)
    assert factors == factors_from_totals(free_misfit_totals(data, wls, cfg))
    assert factors[2] < 1e-3 < factors[0]  # exact differences: a tiny factor


@pytest.mark.parametrize("model", ["cv", "ca"])
def test_exact_phase_gives_the_displacements(flights, model: str) -> None:  # type: ignore[no-untyped-def]
    """Noise-free pseudoranges and range rates: the displacements within 2 mm with or without phase
    (the simulator's truth and models agree to ~1 mm: measured 0.67 mm RMS, 1.5 mm max).
    1 m pseudorange noise: the exact phase keeps them there (measured 0.67 mm RMS), without it they
    are off by 0.09 m (ca) to 0.71 m (cv) RMS; the positions 0.10 m instead of 0.59-1.09 m."""
    cfg, ref = replace(flights["cfg"], kalman=replace(flights["cfg"].kalman, model=model)), flights["ref"]
    exact = _with_phase(flights["none"], flights["phase"], cfg)
    kf = run_kalman(exact, solve_method(exact, "wls", cfg), cfg, measurements=ALL)
    assert _displacement_error(kf.x_ecef_m, ref).max() < 0.002
    noisy = _with_phase(flights["noise"], flights["phase"], cfg)
    wls = solve_method(noisy, "wls", cfg)
    with_phase = run_kalman(noisy, wls, cfg, measurements=ALL)
    without = run_kalman(noisy, wls, cfg, measurements=PR_DOPPLER)
    assert _displacement_error(with_phase.x_ecef_m, ref).max() < 0.002
    assert _rms(_displacement_error(without.x_ecef_m, ref)) > 0.05
    err = {k: _rms(np.linalg.norm(s.x_ecef_m - ref, axis=1)) for k, s in (("with", with_phase), ("without", without))}
    assert err["with"] < 0.3 * err["without"]


@pytest.mark.parametrize("cycles", [10, 1])
def test_a_cycle_slip_does_not_bias_the_track(flights, cycles: int) -> None:  # type: ignore[no-untyped-def]
    """10 cycles (1.9 m) are flagged by the Doppler check; 1 cycle (0.19 m) passes it and is left to
    the gate, whose statistic is the innovation predicted from the epoch's other differences (from
    the motion model alone, metres, it would not stand out). Either way the track stays that of the
    clean phase (measured 2.4 mm); unflagged and ungated the slip pulls it (measured 0.65 / 6.5 m)."""
    cfg, noisy = flights["cfg"], flights["noise"]
    wls = solve_method(noisy, "wls", cfg)
    clean = run_kalman(_with_phase(noisy, flights["phase"], cfg), wls, cfg, measurements=ALL)
    sat = int(np.flatnonzero(noisy.usable[100:200].all(axis=0))[0])
    slipped = flights["phase"].copy()
    slipped[150:, sat] += cycles * L1_M
    data = _with_phase(noisy, slipped, cfg)
    assert data.phase_slip is not None and data.phase_slip.sum() == (cycles == 10)
    assert np.abs(run_kalman(data, wls, cfg, measurements=ALL).x_ecef_m - clean.x_ecef_m).max() < 0.02
    off = replace(cfg, integrity="off")
    pulled = run_kalman(replace(data, phase_slip=np.zeros_like(data.phase_slip)), wls, off, measurements=ALL)
    assert np.abs(pulled.x_ecef_m - clean.x_ecef_m).max() > 0.1


def test_kinds_are_checked_and_the_gate_is_the_smoothers(flights) -> None:  # type: ignore[no-untyped-def]
    cfg, data = flights["cfg"], flights["noise"]
    for bad in ({"doppler"}, {"pseudorange", "carrier"}, set()):
        with pytest.raises(ConfigError, match="measurements"):
            measurement_kinds(data, cfg, frozenset(bad))
    assert measurement_kinds(data, cfg, None) == PR_DOPPLER  # every kind of the file (it has no phase)
    no_doppler = replace(cfg, measurements=("pseudorange",))
    assert measurement_kinds(data, no_doppler, None) == {"pseudorange"}
    assert measurement_kinds(data, no_doppler, PR_DOPPLER) == PR_DOPPLER  # the kinds asked for rule
    assert gate_threshold(cfg) == pytest.approx(3.2905, abs=1e-4)  # integrity_pfa = 1e-3
    assert gate_threshold(replace(cfg, integrity_pfa=0.05)) == pytest.approx(1.95996, abs=1e-5)
    assert gate_threshold(replace(cfg, integrity="off")) is None
