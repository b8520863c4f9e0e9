"""The ``smoother``: pseudoranges (range rates, phase) of whole segments in the measurement domain under a
fixed motion model; the default ``--lag 3`` run on a file with Doppler (quadrature lag 3, every kind)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gnss_cli.config import load_config
from gnss_cli.errors import ConfigError
from gnss_cli.gnss.frames import geodetic2ecef
from gnss_cli.io.reference import reference_from_csv
from gnss_cli.pipeline import load_epochs, process, solve_method
from gnss_cli.pipeline.integrity import take_epochs
from gnss_cli.pipeline.smoother import MAX_STEP_INTERVALS, default_measurements, smooth_segments
from gnss_cli.sim.error_sources import parse_error_list
from gnss_cli.sim.scenario import ScenarioConfig, epochs_gps_s, run_scenario, write_scenario

from flight_scenarios import simulate_flight

BASE = {"methods": "wls,smoother", "smoother.lag": 3, "iono": "none", "tropo": "none"}
PR, PR_DOP = frozenset({"pseudorange"}), frozenset({"pseudorange", "doppler"})
FIXTURE = Path(__file__).resolve().parents[1] / "data" / "smoother_default_flight.csv"


def _err(x: np.ndarray, ref: np.ndarray) -> np.ndarray:
    return np.linalg.norm(x - ref, axis=1)


def _rms(x: np.ndarray, ref: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(_err(x, ref) ** 2)))


def _smooth(data, wls, cfg, motion: str = "quadrature", measurements=PR_DOP, **kw):  # type: ignore[no-untyped-def]
    return smooth_segments(data, wls, cfg, motion=motion, lag=3, measurements=measurements, **kw)


@pytest.fixture(scope="module")
def noisy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulate_flight(tmp_path_factory.mktemp("noisy"), "noise")


def test_default_run_equals_the_previous_implementation(tmp_path: Path) -> None:
    """``--method smoother`` (quadrature lag 3, every kind present): its positions and velocities
    are those written by the code it replaced (``stls --lag 3 --model doppler`` then; tests/data).
    Its DOP columns are now the geometry of the pseudoranges, no longer its covariance."""
    d = simulate_flight(tmp_path, "noise", duration_s=120.0)
    # the weights of the recorded run (before the C/N0 term): the implementation is what is compared
    res = process(d / "obs.rnx", [d / "nav.rnx"], load_config(None, {**BASE, "weights.cn0_model": "off"}))
    sol = res.solutions["smoother"]
    ref = np.loadtxt(FIXTURE, delimiter=",", skiprows=2)
    assert sol.method == "smoother" and res.models[0].model == "motion quadrature"
    np.testing.assert_allclose(res.epochs.time_gps_s, ref[:, 0], rtol=0, atol=1e-3)
    np.testing.assert_allclose(sol.x_ecef_m, ref[:, 1:4], rtol=0, atol=1e-6)
    np.testing.assert_allclose(sol.vel_ecef_m_s, ref[:, 4:7], rtol=0, atol=1e-8)


def test_default_lag3_is_the_measurement_domain_solution(noisy: Path) -> None:
    """White noise: far below the fixes and below the identified stls on the same measurements
    (this flight: 0.47 m against 0.57 m for stls with its spans tied, in 15-epoch windows;
    measured earlier on seeds 11-15 over 600 s, before stls used the range rates: 0.31 against
    1.06 x the truth-tuned KF+RTS); the multi-epoch GDOP below the snapshot
    GDOP; velocities better than the per-epoch Doppler velocities."""
    res = process(noisy / "obs.rnx", [noisy / "nav.rnx"], load_config(None, BASE))
    ref = reference_from_csv(noisy / "truth.csv", res.epochs.time_gps_s)
    wls, stls = res.solutions["wls"], res.solutions["smoother"]
    ident = process(noisy / "obs.rnx", [noisy / "nav.rnx"],
                    load_config(None, {**BASE, "methods": "wls,stls", "stls.lag": 3})).solutions["stls"]
    assert (stls.status == "ok").all()
    assert len(res.models) == 1 and res.models[0].model == "motion quadrature" and "measurement domain" in res.models[0].message
    assert "motion quadrature (lag 3), pseudorange+doppler" in res.models[0].message
    assert res.settings["smoother"].model == "motion quadrature" and res.settings["smoother"].lag == "3"
    assert _rms(stls.x_ecef_m, ref) < _rms(ident.x_ecef_m, ref)
    assert _rms(stls.x_ecef_m, ref) < 0.2 * _rms(wls.x_ecef_m, ref)
    assert np.all(stls.gdop < wls.gdop)
    assert np.all(np.isfinite(stls.cov_m2[:, :4, :4]))
    # the predicted sd is the size of the actual error (not 10x off either way)
    sd = np.sqrt(np.mean(np.trace(stls.cov_m2[:, :3, :3], axis1=1, axis2=2)))
    assert 0.3 < sd / _rms(stls.x_ecef_m, ref) < 3.0
    truth_v = pd.read_csv(noisy / "truth.csv")[["vx_m_s", "vy_m_s", "vz_m_s"]].to_numpy()
    assert _rms(stls.vel_ecef_m_s, truth_v) < _rms(wls.vel_ecef_m_s, truth_v)


def test_noise_free_flight_gives_the_truth_to_a_centimetre(tmp_path: Path) -> None:
    d = simulate_flight(tmp_path, "none")
    res = process(d / "obs.rnx", [d / "nav.rnx"], load_config(None, BASE))
    ref = reference_from_csv(d / "truth.csv", res.epochs.time_gps_s)
    err = _err(res.solutions["smoother"].x_ecef_m, ref)
    assert np.sqrt(np.mean(err**2)) <= 0.01 and err.max() <= 0.02


def _simulate(out: Path, trajectory: str, duration_s: float = 120.0) -> Path:
    """A noise-free GPS file at 1 Hz: ``static``, or ``cv`` / ``ca`` (a straight ECEF line at constant
    velocity / acceleration from the default site, written as a CSV trajectory)."""
    base = ScenarioConfig()
    cfg = replace(base, duration_s=duration_s, interval_s=1.0, seed=3, errors=base.errors.with_sources(parse_error_list("none")))
    if trajectory != "static":
        t = epochs_gps_s(cfg)
        knots = np.linspace(t[0], t[-1], 7)
        s = (knots - t[0])[:, None]
        v0, a = np.array([20.0, -15.0, 5.0]), np.array([0.3, 0.2, -0.1]) * (trajectory == "ca")
        site = geodetic2ecef(np.deg2rad(base.latitude_deg), np.deg2rad(base.longitude_deg), base.height_m)
        pos, vel = site + v0 * s + 0.5 * a * s**2, v0 + a * s
        pd.DataFrame({"t_gps_s": knots, "x_m": pos[:, 0], "y_m": pos[:, 1], "z_m": pos[:, 2],
                      "vx_m_s": vel[:, 0], "vy_m_s": vel[:, 1], "vz_m_s": vel[:, 2]}).to_csv(out / "path.csv", index=False)
        trajectory = f"csv:{out / 'path.csv'}"
    write_scenario(run_scenario(replace(cfg, trajectory=trajectory)), out)
    return out


@pytest.mark.parametrize("measurements", [PR, PR_DOP], ids=["pseudorange", "pseudorange+doppler"])
@pytest.mark.parametrize("motion", ["static", "cv", "ca"])
def test_each_motion_reproduces_a_noise_free_trajectory_it_holds_for(tmp_path: Path, motion: str,
                                                                     measurements: frozenset[str]) -> None:
    """Noise-free pseudoranges (and range rates) of a static receiver, a constant velocity and a constant
    acceleration: the motion that holds gives the truth to a centimetre, with Doppler and without."""
    d = _simulate(tmp_path, motion)
    cfg = load_config(None, BASE)
    data = load_epochs(d / "obs.rnx", [d / "nav.rnx"], cfg)
    sol, models = _smooth(data, solve_method(data, "wls", cfg), cfg, motion, measurements)
    ref = reference_from_csv(d / "truth.csv", data.time_gps_s)
    truth_v = pd.read_csv(d / "truth.csv")[["vx_m_s", "vy_m_s", "vz_m_s"]].to_numpy()
    assert (sol.status == "ok").all() and all(m.status == "converged" for m in models)
    assert _err(sol.x_ecef_m, ref).max() <= 0.01
    assert np.abs(sol.vel_ecef_m_s - truth_v).max() <= 0.01


@pytest.mark.parametrize("motion", ["quadrature", "cv", "ca", "static"])
def test_pseudoranges_alone_run_for_every_motion(noisy: Path, motion: str) -> None:
    """No range rates: the velocities come from the motion model; every epoch is solved, the kinematic
    motions inside the WLS scatter (with their loose default priors: a jerk of 3 m/s^3, PSDs of 10)
    (static cannot follow a flight, but is still a solution)."""
    cfg = load_config(None, BASE)
    data = load_epochs(noisy / "obs.rnx", [noisy / "nav.rnx"], cfg)
    wls = solve_method(data, "wls", cfg)
    sol, models = _smooth(replace(data, range_rate_m_s=None), wls, cfg, motion, PR)
    ref = reference_from_csv(noisy / "truth.csv", data.time_gps_s)
    assert (sol.status == "ok").all() and np.isfinite(sol.x_ecef_m).all() and np.isfinite(sol.vel_ecef_m_s).all()
    assert "range rates" not in models[0].message and f"motion {motion}" in models[0].message
    if motion != "static":
        assert _rms(sol.x_ecef_m, ref) < 0.7 * _rms(wls.x_ecef_m, ref)  # measured 0.60 (quadrature, cv, ca)
    else:
        assert np.all(sol.vel_ecef_m_s == 0.0)


def test_a_degenerate_segment_keeps_the_wls_fixes_by_status(noisy: Path) -> None:
    """Two epochs between two gaps, pseudoranges alone, quadrature: their velocities are free (one step,
    two velocities, no prior), so that segment is not smoothed -- its epochs keep the WLS fixes as
    ``fallback_wls`` and its record fails -- and the rest is."""
    cfg = load_config(None, BASE)
    data = load_epochs(noisy / "obs.rnx", [noisy / "nav.rnx"], cfg)
    usable = data.usable.copy()
    usable[[50, 51, 54, 55]] = False
    data = replace(data, usable=usable)
    wls = solve_method(data, "wls", cfg)
    sol, models = _smooth(data, wls, cfg, "quadrature", PR)
    assert list(sol.status[52:54]) == ["fallback_wls"] * 2
    np.testing.assert_array_equal(sol.x_ecef_m[52:54], wls.x_ecef_m[52:54])
    failed = [m for m in models if m.status == "failed"]
    assert len(failed) == 1 and failed[0].n_epochs == 2 and "degenerate" in failed[0].message
    others = np.setdiff1d(np.arange(data.time_gps_s.size), [50, 51, 52, 53, 54, 55])
    assert (sol.status[others] == "ok").all()
    cv, _ = _smooth(data, wls, cfg, "cv", PR)  # white acceleration ties the two velocities: solved
    assert (cv.status[52:54] == "ok").all()


@pytest.mark.parametrize("motion, kinds, bound_m", [("quadrature", PR, 2e-3), ("cv", PR_DOP, 2e-3), ("ca", PR_DOP, 2e-3),
                                                     ("quadrature", PR_DOP, 2e-2)])
def test_missed_epochs_are_bridged(tmp_path: Path, motion: str, kinds: frozenset[str], bound_m: float) -> None:
    """Epochs 1 and 50-52 missing from a noise-free flight (the Yamatogawa walk's first step is two
    seconds): the steps of 2 and 4 intervals stay inside the segment -- one segment, every epoch
    ``ok`` -- and the track is the truth to the millimetre; with exact range rates the quadrature
    rule's own error over the 4 s step of a manoeuvre remains (1.5 cm with lag 3, its weights at the
    epochs' own times; 3.4 cm with the weights of even steps)."""
    d = simulate_flight(tmp_path, "none", duration_s=120.0)
    cfg = load_config(None, BASE)
    full = load_epochs(d / "obs.rnx", [d / "nav.rnx"], cfg)
    rows = np.r_[0, 2:50, 53:full.time_gps_s.size]
    data = take_epochs(full, rows)
    wls = solve_method(data, "wls", cfg)
    ref = reference_from_csv(d / "truth.csv", data.time_gps_s)
    sol, models = _smooth(data, wls, cfg, motion, kinds)
    assert len(models) == 1 and models[0].n_epochs == rows.size
    assert "bridging 2 steps of missed epochs" in models[0].message
    assert (sol.status == "ok").all()
    assert _err(sol.x_ecef_m, ref).max() < bound_m


def test_an_epoch_alone_between_long_gaps_keeps_its_wls_fix_by_status(noisy: Path) -> None:
    """A first epoch six intervals before the rest (a step longer than the bridged
    ``MAX_STEP_INTERVALS``): a segment of one, not smoothed, so it keeps the WLS fix as
    ``fallback_wls`` -- not ``ok``, which names a smoothed epoch -- and the rest is smoothed."""
    cfg = load_config(None, BASE)
    full = load_epochs(noisy / "obs.rnx", [noisy / "nav.rnx"], cfg)
    assert MAX_STEP_INTERVALS == 5
    rows = np.r_[0, 6:full.time_gps_s.size]
    data = take_epochs(full, rows)
    wls = solve_method(data, "wls", cfg)
    sol, models = _smooth(data, wls, cfg)
    assert wls.status[0] == "ok" and sol.status[0] == "fallback_wls"
    np.testing.assert_array_equal(sol.x_ecef_m[0], wls.x_ecef_m[0])
    assert (sol.status[1:] == "ok").all() and not np.array_equal(sol.x_ecef_m[1:], wls.x_ecef_m[1:])
    assert sum(m.n_epochs for m in models) == rows.size - 1


def test_epochs_with_one_to_three_satellites_get_positions(noisy: Path) -> None:
    """Epochs left with 3, 2 or 1 satellites have no WLS fix; in the measurement domain they are
    solved (``ok``, ``n_sat`` their pseudoranges) and stay near the truth."""
    cfg = load_config(None, BASE)
    data = load_epochs(noisy / "obs.rnx", [noisy / "nav.rnx"], cfg)
    usable = data.usable.copy()
    keep = {range(100, 110): 3, range(150, 160): 2, range(200, 204): 1}
    for span, n_keep in keep.items():
        for t in span:
            usable[t, np.flatnonzero(usable[t])[n_keep:]] = False
    data = replace(data, usable=usable)
    wls = solve_method(data, "wls", cfg)
    sol, _ = _smooth(data, wls, cfg)
    ref = reference_from_csv(noisy / "truth.csv", data.time_gps_s)
    few = np.concatenate([np.arange(s.start, s.stop) for s in keep])
    assert not np.any(wls.status[few] == "ok")
    assert np.all(sol.status[few] == "ok")
    for span, n_keep in keep.items():
        idx = np.arange(span.start, span.stop)
        assert np.all(sol.n_sat[idx] == n_keep)
        assert _err(sol.x_ecef_m[idx], ref[idx]).max() < 2.0  # the WLS fixes scatter 3 m RMS
    assert np.all(np.isfinite(sol.gdop[few]))


def test_measurements_the_file_lacks_or_unknown_are_config_errors(noisy: Path) -> None:
    cfg = load_config(None, BASE)
    data = load_epochs(noisy / "obs.rnx", [noisy / "nav.rnx"], cfg)
    wls = solve_method(data, "wls", cfg)
    assert default_measurements(data, cfg) == PR_DOP  # the simulator writes no phase
    assert default_measurements(data, load_config(None, {**BASE, "measurements": "pseudorange"})) == PR
    with pytest.raises(ConfigError, match="doppler needs Doppler"):
        _smooth(replace(data, range_rate_m_s=None), wls, cfg, measurements=PR_DOP)
    with pytest.raises(ConfigError, match="phase needs carrier-phase"):
        _smooth(data, wls, cfg, measurements={"pseudorange", "phase"})
    for bad in ({"doppler"}, {"pseudorange", "carrier"}):
        with pytest.raises(ConfigError, match="measurements: expected"):
            _smooth(data, wls, cfg, measurements=bad)
    with pytest.raises(ConfigError, match="motion: expected"):
        _smooth(data, wls, cfg, motion="pva")


def test_lag_selects_the_quadrature_rule(noisy: Path) -> None:
    """The model record's kernel is the lag's rule: lag 1 the trapezoid (two blocks), lag 3 four."""
    for lag, blocks in ((1, 2), (3, 4)):
        res = process(noisy / "obs.rnx", [noisy / "nav.rnx"], load_config(None, {**BASE, "smoother.lag": lag}))
        rec = res.models[0].kernel
        assert rec is not None and np.asarray(rec.kernel_R).shape == (3, 6 * blocks)


def test_a_faulty_satellite_is_excluded_by_the_residual_gate(noisy: Path) -> None:
    """A 30 m ramp on one satellite's pseudoranges over 40 epochs (below what the snapshot FDE
    always sees at one epoch): the gate excludes those rows (``excluded``), and the track stays
    as good as without the fault; with ``integrity = "off"`` the fault pulls it."""
    cfg = load_config(None, BASE)
    data = load_epochs(noisy / "obs.rnx", [noisy / "nav.rnx"], cfg)
    ref = reference_from_csv(noisy / "truth.csv", data.time_gps_s)
    span = np.arange(100, 140)
    sat = int(np.flatnonzero(data.usable[span].all(axis=0))[0])
    pr = data.pr_corrected_m.copy()
    pr[span, sat] += np.linspace(10.0, 30.0, span.size)
    faulty = replace(data, pr_corrected_m=pr)
    clean_err = _err(_smooth(data, solve_method(data, "wls", cfg), cfg)[0].x_ecef_m[span], ref[span])
    wls = solve_method(faulty, "wls", cfg)
    sol, _ = _smooth(faulty, wls, cfg)
    assert sol.excluded is not None and sol.excluded[span, sat].mean() > 0.9
    err = _err(sol.x_ecef_m[span], ref[span])
    assert np.sqrt(np.mean(err**2)) < 1.2 * np.sqrt(np.mean(clean_err**2)) + 0.05
    off = load_config(None, {**BASE, "integrity": "off"})
    pulled = _err(_smooth(faulty, solve_method(faulty, "wls", off), off)[0].x_ecef_m[span], ref[span])
    assert np.sqrt(np.mean(pulled**2)) > 2 * np.sqrt(np.mean(err**2))
