"""Time-differenced carrier phase in the ``smoother`` (``measurements`` with ``phase``).

`simulate_flight` writes no carrier phase, so the phase is made here from a noise-free flight of the
same seed (same orbits, trajectory and receiver clock): its corrected pseudorange is the exact
range plus clock, and a constant per satellite (the unknown ambiguity) is added.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gnss_cli.config import load_config
from gnss_cli.errors import ConfigError
from gnss_cli.gnss.carrier import phase_slips
from gnss_cli.io.reference import reference_from_csv
from gnss_cli.pipeline import load_epochs, solve_method
from gnss_cli.behavior.kinematic_solve import Motion
from gnss_cli.pipeline.smoother import default_measurements, smooth_segments, solve_segments
from gnss_cli.pipeline.results import EpochData

from flight_scenarios import simulate_flight

BASE = {"methods": "wls,smoother", "smoother.lag": 3, "iono": "none", "tropo": "none"}
L1_M = 299792458.0 / 1575.42e6


def _smooth_default(data: EpochData, wls, cfg, measurements: frozenset[str] | None = None):  # type: ignore[no-untyped-def]
    """The default run: quadrature lag 3, every kind of measurement present (and configured)."""
    kinds = default_measurements(data, cfg) if measurements is None else measurements
    return smooth_segments(data, wls, cfg, motion="quadrature", lag=3, measurements=kinds)


def _segments_default(data: EpochData, wls, cfg, lag: int = 3):  # type: ignore[no-untyped-def]
    """The run of every segment with every kind of measurement present (``data`` has phase here)."""
    return solve_segments(data, wls, cfg, Motion("quadrature", lag), default_measurements(data, cfg))


def _rms(x: np.ndarray, ref: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(np.sum((x - ref) ** 2, axis=1))))


@pytest.fixture(scope="module")
def flights(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    cfg = load_config(None, BASE)
    out: dict[str, object] = {"cfg": cfg}
    for errors in ("none", "noise"):
        d = simulate_flight(tmp_path_factory.mktemp(errors), errors)
        data = load_epochs(d / "obs.rnx", [d / "nav.rnx"], cfg)
        assert data.phase_m is None  # the simulator writes no phase
        out[errors] = data
        out["ref"] = reference_from_csv(d / "truth.csv", data.time_gps_s)
    exact, noisy = out["none"], out["noise"]
    assert isinstance(exact, EpochData) and isinstance(noisy, EpochData)
    np.testing.assert_allclose(exact.sat_ecef_m, noisy.sat_ecef_m, atol=1e-3)  # the same sky: one phase for both
    ambiguity = L1_M * np.random.default_rng(5).integers(-10**6, 10**6, exact.sv.size)
    out["phase"] = exact.pr_corrected_m + ambiguity
    return out


def _with_phase(data: EpochData, phase: np.ndarray, cfg, lli: np.ndarray | None = None) -> EpochData:  # type: ignore[no-untyped-def]
    lli = np.zeros(phase.shape) if lli is None else lli
    slip = phase_slips(data.time_gps_s, phase, data.range_rate_m_s, lli, cfg.phase_slip_m)
    return replace(data, phase_m=np.where(data.usable, phase, np.nan), phase_slip=slip)


def test_exact_phase_keeps_exact_data_exact(flights) -> None:  # type: ignore[no-untyped-def]
    cfg, ref = flights["cfg"], flights["ref"]
    data = _with_phase(flights["none"], flights["phase"], cfg)
    sol, models = _smooth_default(data, solve_method(data, "wls", cfg), cfg)
    assert "phase pairs" in models[0].message
    err = np.linalg.norm(sol.x_ecef_m - ref, axis=1)
    assert np.sqrt(np.mean(err**2)) <= 0.01 and err.max() <= 0.02


def test_exact_phase_averages_the_pseudorange_noise(flights) -> None:  # type: ignore[no-untyped-def]
    """The differences fix the trajectory's shape: 1 m pseudorange noise averages over the segment."""
    cfg, ref, noisy = flights["cfg"], flights["ref"], flights["noise"]
    wls = solve_method(noisy, "wls", cfg)
    without = _rms(_smooth_default(noisy, wls, cfg)[0].x_ecef_m, ref)
    data = _with_phase(noisy, flights["phase"], cfg)
    run = _segments_default(data, wls, cfg, 3)
    assert run is not None and "phase" in run.measurements and run.factors[2] < 1e-3  # exact differences: a tiny factor
    assert _rms(run.x_ecef_m, ref) < 0.5 * without
    off = load_config(None, {**BASE, "measurements": "pseudorange,doppler"})
    assert _rms(_smooth_default(data, wls, off)[0].x_ecef_m, ref) == pytest.approx(without, abs=1e-9)


@pytest.mark.parametrize("motion", ["quadrature", "cv"])
def test_phase_without_doppler_ties_the_track(flights, motion: str) -> None:  # type: ignore[no-untyped-def]
    """Pseudoranges and phase, no range rates: exact data stay exact, and exact phase averages the
    pseudorange noise of a flight far below the pseudoranges alone (both motions)."""
    cfg, ref = flights["cfg"], flights["ref"]
    kinds = frozenset({"pseudorange", "phase"})
    exact = _with_phase(flights["none"], flights["phase"], cfg)
    sol, models = smooth_segments(exact, solve_method(exact, "wls", cfg), cfg, motion=motion, lag=3, measurements=kinds)
    assert "phase pairs" in models[0].message and "range rates" not in models[0].message
    assert np.linalg.norm(sol.x_ecef_m - ref, axis=1).max() <= 0.02
    noisy = _with_phase(flights["noise"], flights["phase"], cfg)
    wls = solve_method(noisy, "wls", cfg)
    alone = smooth_segments(noisy, wls, cfg, motion=motion, lag=3, measurements={"pseudorange"})[0]
    tied = smooth_segments(noisy, wls, cfg, motion=motion, lag=3, measurements=kinds)[0]
    assert (tied.status == "ok").all() and _rms(tied.x_ecef_m, ref) < 0.5 * _rms(alone.x_ecef_m, ref)


@pytest.mark.parametrize("cycles", [10, 1])
def test_a_cycle_slip_does_not_bias_the_track(flights, cycles: int) -> None:  # type: ignore[no-untyped-def]
    """A slip of 10 cycles (1.9 m) is flagged by the Doppler check; one of 1 cycle (0.19 m, within
    the Doppler's reach) by the residual gate. Either way the track stays that of the clean phase,
    and a phase that keeps the slip unflagged and ungated pulls it."""
    cfg, noisy = flights["cfg"], flights["noise"]
    wls = solve_method(noisy, "wls", cfg)
    clean = _segments_default(_with_phase(noisy, flights["phase"], cfg), wls, cfg, 3)
    sat = int(np.flatnonzero(noisy.usable[100:200].all(axis=0))[0])
    slipped = flights["phase"].copy()
    slipped[150:, sat] += cycles * L1_M
    data = _with_phase(noisy, slipped, cfg)
    assert data.phase_slip is not None
    assert data.phase_slip[150, sat] == (cycles == 10) and data.phase_slip.sum() == (cycles == 10)
    run = _segments_default(data, wls, cfg, 3)
    assert clean is not None and run is not None
    assert np.abs(run.x_ecef_m - clean.x_ecef_m).max() < 0.02
    off = load_config(None, {**BASE, "integrity": "off"})
    pulled = _segments_default(replace(data, phase_slip=np.zeros_like(data.phase_slip)), wls, off, 3)
    assert pulled is not None and np.abs(pulled.x_ecef_m - clean.x_ecef_m).max() > 0.05


def test_many_small_slips_at_once_do_not_bias_the_track(flights) -> None:  # type: ignore[no-untyped-def]
    """Urban slips: one to three cycles (within the Doppler check's reach, unflagged) on every
    satellite but four, at the same epochs, several times. The gate takes every row above it,
    so the track stays that of the clean phase; one row per pair and pass (the rule before)
    could not keep up."""
    cfg, noisy = flights["cfg"], flights["noise"]
    wls = solve_method(noisy, "wls", cfg)
    clean = _segments_default(_with_phase(noisy, flights["phase"], cfg), wls, cfg, 3)
    sats = np.flatnonzero(noisy.usable[60:260].all(axis=0))[4:]
    assert sats.size >= 4
    slipped = flights["phase"].copy()
    for t in (80, 120, 150, 200, 240):
        slipped[t:, sats] += (1 + np.arange(sats.size) % 3) * L1_M
    data = _with_phase(noisy, slipped, cfg)
    assert data.phase_slip is not None and not data.phase_slip.any()  # none flagged: the gate's alone
    run = _segments_default(data, wls, cfg, 3)
    assert clean is not None and run is not None
    # within 10 cm of the clean phase's track (4 cm measured; the rule before: 93 cm)
    assert np.abs(run.x_ecef_m - clean.x_ecef_m).max() < 0.1


def test_loss_of_lock_indicator_breaks_the_difference(flights) -> None:  # type: ignore[no-untyped-def]
    """Bit 0 of the indicator at t drops the pair (t-1, t); bit 1 (half cycle) does not."""
    cfg, noisy = flights["cfg"], flights["noise"]
    lli = np.zeros(noisy.pr_corrected_m.shape)
    lli[40, 2], lli[41, 3] = 1, 2
    data = _with_phase(noisy, flights["phase"], cfg, lli)
    assert data.phase_slip is not None and data.phase_slip[40, 2] and not data.phase_slip[41, 3]


@pytest.mark.parametrize(("key", "value", "message"), [("phase_sigma_m", 0.0, "phase_sigma_m"),
                                                       ("phase_slip_m", -1.0, "phase_slip_m"),
                                                       ("phase_sigma_m", "0.02x", "bad value"),
                                                       ("measurements", "pseudorange,phaze", "measurements")])
def test_bad_phase_settings_are_config_errors(key: str, value: object, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_config(None, {**BASE, key: value})


def test_reader_gives_the_indicators_of_the_file(tmp_path: Path) -> None:
    """The indicators of the L1 field of a RINEX 2 file equal the column after each value, read
    here character by character; blank is 0, and none without the ``lli`` code."""
    from gnss_cli.io.rinex import read_obs

    text = """     2.10           OBSERVATION DATA    G (GPS)             RINEX VERSION / TYPE
     3    C1    L1    D1                                    # / TYPES OF OBSERV 
  2010     1     6     5    57    3.0000000     GPS         TIME OF FIRST OBS   
                                                            END OF HEADER       
 10  1  6  5 57  3.0000000  0  2G02G04
  21128675.686 7     -7818.26327      2781.846 7
  20670375.121 8      1562.632 8       211.206 8
 10  1  6  5 57  4.0000000  0  2G02G04
  21128147.158 7    -10597.3281       2779.466 7
  20670335.688 8      1357.12628       208.050 8
"""
    path = tmp_path / "lli.10o"
    path.write_text(text)
    ds = read_obs(path, codes=["C1", "L1", "L1lli"])
    np.testing.assert_array_equal(ds["L1lli"].values, [[2.0, 0.0], [1.0, 2.0]])
    assert float(ds["L1"].values[1, 0]) == -10597.328
    assert "L1lli" not in read_obs(path, codes=["C1", "L1"])


def test_the_modelled_ionosphere_advances_the_carrier(tmp_path: Path) -> None:
    """The carrier is advanced by the ionosphere that delays the code. A static GPS receiver at 30 s
    through a morning (the Klobuchar delay rising by metres), simulated with exactly the broadcast
    ionosphere and 1 m code noise: with the phase pairs the smoother and the kf average the noise away
    (0.19 and 0.28 m 3D RMS measured, WLS 3.4 m). With the model's delay given the pseudorange's sign
    in the phase, twice its change would accumulate into the track: 1.34 m for either."""
    from gnss_cli.pipeline import process
    from gnss_cli.sim.scenario import ScenarioConfig, config_from_mapping, run_scenario, write_scenario

    sim = config_from_mapping({"simulate": {"trajectory": "static", "start": "2024-03-01T06:00:00",
                                            "duration_s": 21600.0, "interval_s": 30.0, "phase": True,
                                            "errors": "iono,noise"},
                               "errors": {"iono_factor": 1.0}}, ScenarioConfig())
    write_scenario(run_scenario(sim), tmp_path)
    cfg = load_config(None, {"methods": "wls,smoother,kf", "tropo": "none", "measurements": "all"})
    result = process(tmp_path / "obs.rnx", [tmp_path / "nav.rnx"], cfg)
    assert result.settings["smoother"].measurements == "pseudorange+doppler+phase"
    ref = reference_from_csv(tmp_path / "truth.csv", result.epochs.time_gps_s)
    rms = {m: _rms(result.solutions[m].x_ecef_m, ref) for m in ("wls", "smoother", "kf")}
    assert rms["wls"] > 2.0
    assert rms["smoother"] < 0.3 and rms["kf"] < 0.4, rms


def test_iono_free_uses_the_iono_free_carrier(tmp_path: Path) -> None:
    """``--iono iono-free`` combines the two signals' phases as it combines the pseudoranges. A static
    dual-frequency receiver at 30 s through a morning, the real ionosphere 1.25 x the broadcast one,
    1 m code noise on each signal: the smoother with the phase pairs reaches 0.46 m 3D RMS (WLS with
    the iono-free pseudoranges 10.9 m). With the first signal's phase alone the ionosphere's change
    stays in every pair, and the smoother drifts to 3.6 m."""
    from gnss_cli.pipeline import process
    from gnss_cli.sim.scenario import ScenarioConfig, config_from_mapping, run_scenario, write_scenario

    sim = config_from_mapping({"simulate": {"trajectory": "static", "start": "2024-03-01T06:00:00",
                                            "duration_s": 21600.0, "interval_s": 30.0, "phase": True,
                                            "dual_frequency": True, "errors": "iono,noise"}}, ScenarioConfig())
    write_scenario(run_scenario(sim), tmp_path)
    cfg = load_config(None, {"methods": "wls,smoother", "tropo": "none", "iono": "iono-free", "measurements": "all"})
    result = process(tmp_path / "obs.rnx", [tmp_path / "nav.rnx"], cfg)
    assert result.settings["smoother"].measurements == "pseudorange+doppler+phase"
    ref = reference_from_csv(tmp_path / "truth.csv", result.epochs.time_gps_s)
    rms = {m: _rms(result.solutions[m].x_ecef_m, ref) for m in ("wls", "smoother")}
    assert rms["wls"] > 5.0
    assert rms["smoother"] < 0.8, rms


def test_phase_without_doppler_is_used_and_checked_against_the_code(tmp_path: Path) -> None:
    """Many 30 s station files have carrier phase but no Doppler: the phase differences are used
    all the same (the wavelengths come from the signals), with their slips found by the loss-of-lock
    indicator and by the pseudoranges (:data:`~gnss_cli.gnss.carrier.CODE_SLIP_M`). The static
    morning of the test above without Doppler: the smoother with phase reaches 0.27 m 3D RMS (WLS
    3.4 m); a slip of 200 cycles put into one satellite's phase adds its own flag and no other."""
    from gnss_cli.pipeline import process
    from gnss_cli.sim.scenario import ScenarioConfig, config_from_mapping, run_scenario, write_scenario

    sim = config_from_mapping({"simulate": {"trajectory": "static", "start": "2024-03-01T06:00:00",
                                            "duration_s": 21600.0, "interval_s": 30.0, "phase": True,
                                            "doppler": False, "errors": "iono,noise"},
                               "errors": {"iono_factor": 1.0}}, ScenarioConfig())
    write_scenario(run_scenario(sim), tmp_path)
    cfg = load_config(None, {"methods": "wls,smoother", "tropo": "none", "measurements": "all"})
    result = process(tmp_path / "obs.rnx", [tmp_path / "nav.rnx"], cfg)
    assert result.epochs.range_rate_m_s is None
    assert result.settings["smoother"].measurements == "pseudorange+phase"
    ref = reference_from_csv(tmp_path / "truth.csv", result.epochs.time_gps_s)
    rms = {m: _rms(result.solutions[m].x_ecef_m, ref) for m in ("wls", "smoother")}
    assert rms["wls"] > 2.0 and rms["smoother"] < 0.4, rms

    data = load_epochs(tmp_path / "obs.rnx", [tmp_path / "nav.rnx"], cfg)
    assert data.phase_m is not None and data.phase_slip is not None
    # the simulated code noise grows to 8 m at 5 deg elevation: a few pairs there are taken for slips
    assert data.phase_slip.sum() < 0.05 * np.isfinite(data.phase_m).sum()
    t, sat = 300, int(np.flatnonzero(np.isfinite(data.phase_m[299:302]).all(axis=0) & ~data.phase_slip[300])[0])
    slipped = data.phase_m.copy()
    slipped[t:, sat] += 200 * L1_M
    none = np.full(slipped.shape, np.nan)
    flags = phase_slips(data.time_gps_s, slipped, none, np.zeros(slipped.shape), cfg.phase_slip_m, data.pr_corrected_m)
    assert flags[t, sat] and (flags ^ data.phase_slip).sum() == 1  # its own flag, and no other changed
