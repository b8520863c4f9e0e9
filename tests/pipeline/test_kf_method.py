"""The kf method and the Doppler velocity on simulated flights (truth known) and real files."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gnss_cli.config import load_config
from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic
from gnss_cli.io.reference import reference_from_csv, reference_from_pos
from gnss_cli.pipeline import load_epochs, process, solve_method
from gnss_cli.pipeline.kalman import run_kalman
from gnss_cli.pipeline.kalman_rows import variance_factors
from gnss_cli.pipeline.velocity import solve_velocity
from gnss_cli.sim.error_sources import parse_error_list
from gnss_cli.sim.scenario import ScenarioConfig, run_scenario, write_scenario

# the simulator's noise model, sigma(el) = 1 m sqrt((1 + 1/sin^2 el) / 2), written as the weight model
MATCHED = {"iono": "none", "tropo": "none", "weights.model": "elevation", "weights.a_m": 0.5**0.5,
           "weights.b_m": 0.5**0.5, "doppler_sigma_m_s": 0.05}


def _simulate(out: Path, trajectory: str, errors: str, seed: int = 11, duration_s: float = 600.0) -> Path:
    base = ScenarioConfig()
    cfg = replace(base, trajectory=trajectory, duration_s=duration_s, interval_s=1.0, seed=seed,
                  errors=base.errors.with_sources(parse_error_list(errors)))
    write_scenario(run_scenario(cfg), out)
    return out


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _simulate(tmp_path_factory.mktemp("flight"), "standard-flight", "noise")


@pytest.fixture(scope="module")
def flight_clean(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _simulate(tmp_path_factory.mktemp("clean"), "standard-flight", "none")


def _errors(d: Path, **overrides: object) -> tuple[dict[str, np.ndarray], dict[str, object], np.ndarray]:
    """3D errors per method, the solutions, and the truth velocities."""
    cfg = load_config(None, {"methods": "wls,kf", **overrides})
    result = process(d / "obs.rnx", [d / "nav.rnx"], cfg)
    ref = reference_from_csv(d / "truth.csv", result.epochs.time_gps_s)
    err = {m: np.linalg.norm(s.x_ecef_m - ref, axis=1) for m, s in result.solutions.items()}
    truth_v = pd.read_csv(d / "truth.csv")[["vx_m_s", "vy_m_s", "vz_m_s"]].to_numpy()
    return err, result.solutions, truth_v


def _rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(v**2)))


def test_kf_smoother_beats_wls_and_its_sd_predicts_the_error(flight):
    err, sols, _ = _errors(flight, **MATCHED)
    assert np.isfinite(err["kf"]).all() and (sols["kf"].status == "ok").all()
    assert _rms(err["kf"]) < 0.5 * _rms(err["wls"])  # measured: 0.91 m against 2.77 m
    sd = np.sqrt(np.trace(sols["kf"].cov_m2[:, :3, :3], axis1=1, axis2=2))
    assert 0.7 < _rms(sd) / _rms(err["kf"]) < 1.4  # measured 1.24


def test_doppler_improves_the_kf_and_the_filter_alone_is_between(flight):
    with_doppler, _, _ = _errors(flight, **MATCHED)
    without, _, _ = _errors(flight, **MATCHED, **{"measurements": "pseudorange"})
    filtered, _, _ = _errors(flight, **MATCHED, **{"kalman.output": "filtered"})
    assert _rms(with_doppler["kf"]) < 0.85 * _rms(without["kf"])  # measured 0.91 m against 1.33 m
    assert _rms(with_doppler["kf"]) < _rms(filtered["kf"]) < 0.6 * _rms(with_doppler["wls"])


def test_noise_free_flight_kf_within_1_cm(flight_clean):
    exact = {"iono": "none", "tropo": "none", "weights.model": "equal", "weights.a_m": 0.001, "doppler_sigma_m_s": 0.001}
    for model in ("cv", "ca"):
        err, sols, truth_v = _errors(flight_clean, **exact, **{"kalman.model": model})
        assert np.nanmax(err["kf"]) < 0.01, model
        assert np.isfinite(err["kf"]).all()
    # the simulator's Doppler (central differences of the light-time range) against the Doppler WLS:
    # 1.5 mm/s RMS; with the Earth-rotation rate term's sign flipped (as RTKLIB 2.4.3 resdop) 4.7 mm/s
    assert _rms(np.linalg.norm(sols["wls"].vel_ecef_m_s - truth_v, axis=1)) < 0.003


def test_doppler_velocity_against_the_truth(flight):
    _, sols, truth_v = _errors(flight, **MATCHED)
    speed = np.linalg.norm(truth_v, axis=1)
    assert speed.max() > 50.0  # a moving receiver: a sign or unit error would show
    for m in ("wls", "kf"):
        dv = np.linalg.norm(sols[m].vel_ecef_m_s - truth_v, axis=1)
        assert _rms(dv) < 0.15, m  # 0.05 m/s Doppler noise; measured 0.097 (wls) and 0.090 (kf)
    assert np.all(sols["wls"].gdop_vel[np.isfinite(sols["wls"].gdop_vel)] > 0.5)


def test_clock_drift_and_static_velocity(tmp_path):
    d = _simulate(tmp_path, "static", "all", seed=12, duration_s=300.0)
    cfg = load_config(None, {"methods": "wls"})
    data = load_epochs(d / "obs.rnx", [d / "nav.rnx"], cfg)
    wls = solve_method(data, "wls", cfg)
    vel = solve_velocity(data, wls.x_ecef_m, wls.sigma_m, cfg)
    truth = pd.read_csv(d / "truth.csv")
    assert _rms(np.linalg.norm(vel.vel_ecef_m_s, axis=1)) < 0.15
    drift_err = vel.clock_drift_m_s - truth["clock_drift_m_s"].to_numpy()
    assert abs(truth["clock_drift_m_s"].iloc[0]) > 0.4 and _rms(drift_err) < 0.1


def test_a_long_gap_restarts_the_filter_and_a_short_one_is_bridged(flight):
    cfg = load_config(None, {"methods": "wls,kf", **MATCHED})
    data = load_epochs(flight / "obs.rnx", [flight / "nav.rnx"], cfg)
    keep = np.r_[0:200, 300:data.time_gps_s.size]  # a 101 s gap > gap_s = 60 s
    fields = ("time_gps_s", "pr_corrected_m", "sat_ecef_m", "ura_m", "usable", "iono_scale", "snr_dbhz", "unused",
              "range_rate_m_s", "sat_vel_ecef_m_s", "sat_clock_drift_s_s")
    gapped = replace(data, **{f: getattr(data, f)[keep] for f in fields if getattr(data, f) is not None})
    second = replace(data, **{f: getattr(data, f)[300:] for f in fields if getattr(data, f) is not None})
    factors = variance_factors(data, solve_method(data, "wls", cfg), cfg)  # else each estimated on its own data
    kf_gapped = run_kalman(gapped, solve_method(gapped, "wls", cfg), cfg, factors=factors)
    kf_second = run_kalman(second, solve_method(second, "wls", cfg), cfg, factors=factors)
    assert np.abs(kf_gapped.x_ecef_m[200:] - kf_second.x_ecef_m).max() < 1e-6  # independent segments

    silent = replace(data, usable=data.usable.copy())
    silent.usable[250:270] = False  # 20 s without measurements: predicted
    wls = solve_method(silent, "wls", cfg)
    kf = run_kalman(silent, wls, cfg)
    assert (kf.status[250:270] == "predicted").all() and np.isfinite(kf.x_ecef_m).all()
    assert (wls.status[250:270] != "ok").all()
    ref = reference_from_csv(flight / "truth.csv", data.time_gps_s)
    assert np.linalg.norm(kf.x_ecef_m[250:270] - ref[250:270], axis=1).max() < 10.0


def test_real_static_doppler_velocity_is_near_zero(rinex_dir):
    d = rinex_dir / "tst2-2020155-urban-static"
    cfg = load_config(None, {"methods": "wls", "environment": "open"})  # the Doppler fix, not the canyon settings
    navs = sorted(d.glob("hksc155d.20?"))
    result = process(d / "2020_06_03_TST_03.obs.gz", navs, cfg)
    v = result.solutions["wls"].vel_ecef_m_s
    speed = np.linalg.norm(v, axis=1)
    assert np.isfinite(speed).mean() > 0.9
    assert np.nanmedian(speed) < 0.3  # a static antenna in an urban canyon


def test_real_doppler_sign_and_units_against_the_pseudorange_rate(rinex_dir):
    """Range rate + c dt_sv_dot equals the time derivative of the corrected pseudorange, up to the
    receiver clock drift common to every satellite (independent of the Doppler code path)."""
    d = rinex_dir / "yamatogawa-2010006-kinematic"
    data = load_epochs(d / "yamatogawa_rover.obs", [d / "brdc0060.10n"], load_config())
    assert data.range_rate_m_s is not None and np.nanmax(np.abs(data.range_rate_m_s)) > 300.0
    dt = np.diff(data.time_gps_s)[:, None]
    dpr = np.diff(data.pr_corrected_m, axis=0) / dt
    rate = data.range_rate_m_s + 299_792_458.0 * data.sat_clock_drift_s_s
    diff = dpr - 0.5 * (rate[1:] + rate[:-1])
    diff -= np.nanmedian(diff, axis=1, keepdims=True)
    assert np.nanmedian(np.abs(diff)) < 0.5  # measured 0.30 m/s: pseudorange noise over 1 s


def test_kf_on_the_yamatogawa_walk(rinex_dir):
    d = rinex_dir / "yamatogawa-2010006-kinematic"
    cfg = load_config(None, {"methods": "wls,kf"})
    result = process(d / "yamatogawa_rover.obs", [d / "brdc0060.10n"], cfg)
    t = result.epochs.time_gps_s
    ref = reference_from_pos(d / "rtk_ref_rover.pos", t, np.zeros_like(t))
    rms = {m: _rms(np.linalg.norm(s.x_ecef_m - ref, axis=1)) for m, s in result.solutions.items()}
    assert rms["kf"] < 0.9 * rms["wls"]  # measured 2.81 m against 3.14 m (2.60 m before the variance factors)
    # walking speed: the RTK trajectory's horizontal speed against the kf's
    ok = np.isfinite(ref).all(axis=1)
    lat, lon, _ = ecef2geodetic(ref[ok])
    rot = ecef2enu_rotation(lat, lon)
    v_ref = np.gradient(ref[ok], t[ok], axis=0)
    h_ref = np.linalg.norm(np.einsum("tij,tj->ti", rot, v_ref)[:, :2], axis=1)
    h_kf = np.linalg.norm(np.einsum("tij,tj->ti", rot, result.solutions["kf"].vel_ecef_m_s[ok])[:, :2], axis=1)
    assert abs(np.median(h_kf) - np.median(h_ref)) < 0.3 and np.median(h_ref) > 0.5


def test_kf_with_its_innovation_gate_in_the_urban_canyon(rinex_dir):
    d = rinex_dir / "tst2-2020155-urban-static"
    truth = np.array([-2418077.2710, 5386069.6872, 2405174.1252])
    result = process(d / "2020_06_03_TST_03.obs.gz", sorted(d.glob("hksc155d.20?")), load_config(None, {"methods": "wls,kf", "environment": "open"}))  # as measured
    tow = np.mod(result.epochs.time_gps_s, 604800.0)
    window = (tow >= 270149) & (tow <= 270305)
    wls, kf = result.solutions["wls"], result.solutions["kf"]
    ok = window & (wls.status == "ok")
    err = {m: np.linalg.norm(s.x_ecef_m - truth, axis=1) for m, s in (("wls", wls), ("kf", kf))}
    assert np.isfinite(err["kf"][window]).all()
    # measured: kf 2.16 m over the 156 truth epochs (10.7 m without the gate, integrity = "off"), WLS 6.8 m over its 152 ok ones
    assert _rms(err["kf"][window]) < 0.6 * _rms(err["wls"][ok])
    assert (kf.n_sat[window] < wls.n_sat[window]).any()  # the gate rejected some of the WLS satellites


def test_epochs_with_two_satellites_are_updated_not_dropped(flight):
    """One minute of a turning flight with two satellites (no WLS fix): the kf updates those
    epochs, which beats coasting on the motion model and, by far, interpolating the WLS fixes;
    its sd covers its error. Measured: 49 m RMS, 63 m coasting, 432 m interpolated."""
    cfg = load_config(None, {"methods": "wls,kf", **MATCHED})
    data = load_epochs(flight / "obs.rnx", [flight / "nav.rnx"], cfg)
    ref = reference_from_csv(flight / "truth.csv", data.time_gps_s)
    gap = slice(250, 310)
    rms, sols = {}, {}
    for kept in (2, 0):
        usable = data.usable.copy()
        for t in range(gap.start, gap.stop):
            usable[t, np.flatnonzero(usable[t])[kept:]] = False
        sparse = replace(data, usable=usable)
        wls = solve_method(sparse, "wls", cfg)
        sols[kept] = kf = run_kalman(sparse, wls, cfg)
        err = np.linalg.norm(kf.x_ecef_m[gap] - ref[gap], axis=1)
        rms[kept] = _rms(err)
        assert (err < 3 * np.sqrt(np.trace(kf.cov_m2[gap, :3, :3], axis1=1, axis2=2))).all()
    assert (wls.status[gap] == "too_few_satellites").all()
    assert (sols[2].status[gap] == "ok").all() and (sols[2].n_sat[gap] == 2).all()
    assert (sols[0].status[gap] == "predicted").all()
    fixed = wls.status == "ok"
    interpolated = np.stack([np.interp(data.time_gps_s[gap], data.time_gps_s[fixed], wls.x_ecef_m[fixed, i])
                             for i in range(3)], axis=1)
    assert rms[2] < 0.9 * rms[0] and rms[2] < 0.2 * _rms(np.linalg.norm(interpolated - ref[gap], axis=1))
