"""``stls --lag L`` in the measurement domain (:mod:`gnss_cli.pipeline.identified`): the truth of a
noise-free trajectory in the model class, the monotone alternation, the misfit of every returned
kernel and trajectory, and the fixed-kernel step against an independent stacked least squares."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gnss_cli.behavior import KernelRepresentation
from gnss_cli.behavior.behavior_solve import shared_modes, solve_in_behavior
from gnss_cli.behavior.multi_epoch import behavior_basis
from gnss_cli.behavior.window_solve import reduce_epochs
from gnss_cli.config import load_config
from gnss_cli.io.reference import reference_from_csv
from gnss_cli.pipeline import load_epochs, solve_method
from gnss_cli.pipeline.behavioral import _schedule, fit_all
from gnss_cli.pipeline.identified import alternate_windows
from gnss_cli.pipeline.kalman import nominal_trajectory
from gnss_cli.pipeline.measurements import measurement_rows
from gnss_cli.pipeline.methods import method_settings, solve_multi_epoch
from gnss_cli.sim.error_sources import parse_error_list
from gnss_cli.sim.scenario import ScenarioConfig, run_scenario, write_scenario

from flight_scenarios import simulate_flight

BASE = {"methods": "wls,stls", "stls.lag": 3, "iono": "none", "tropo": "none"}


def _rms(x: np.ndarray, ref: np.ndarray) -> float:
    e = np.linalg.norm(x - ref, axis=1)
    return float(np.sqrt(np.mean(e[np.isfinite(e)] ** 2)))


def _load(d: Path, measurements: str, **more: object):  # type: ignore[no-untyped-def]
    cfg = load_config(None, {**BASE, "measurements": measurements, **more})
    data = load_epochs(d / "obs.rnx", [d / "nav.rnx"], cfg)
    return cfg, data, solve_method(data, "wls", cfg), np.asarray(reference_from_csv(d / "truth.csv", data.time_gps_s))


@pytest.fixture(scope="module")
def noisy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulate_flight(tmp_path_factory.mktemp("noisy"), "noise", duration_s=120.0)


@pytest.fixture(scope="module")
def arc(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A noise-free constant-speed semicircle: its ENU track satisfies ``(z - 1)(z^2 - 2 cos(w dt) z + 1)``."""
    base = ScenarioConfig()
    cfg = replace(base, trajectory="semicircle", duration_s=120.0, interval_s=1.0, seed=5,
                  errors=base.errors.with_sources(parse_error_list("none")))
    out = tmp_path_factory.mktemp("arc")
    write_scenario(run_scenario(cfg), out)
    return out


@pytest.mark.parametrize("measurements", ["pseudorange", "pseudorange,doppler"])
def test_noise_free_track_in_the_model_class_is_reproduced(arc: Path, measurements: str) -> None:
    """Noise-free pseudoranges (and range rates) of a track a lag-3 shared kernel holds: the
    measurement-domain stls is the truth to 1 cm (it is ~0.2 mm, the simulator's rounding)."""
    cfg, data, wls, ref = _load(arc, measurements)
    sol, models = solve_multi_epoch("stls", data, wls, cfg)
    assert (sol.status == "ok").all()
    assert models and all(m.converged for m in models), [m.message for m in models if not m.converged]
    assert all("measurement domain" in m.message for m in models)
    assert _rms(sol.x_ecef_m, ref) <= 0.01


def _alternated(d: Path, measurements: str):  # type: ignore[no-untyped-def]
    """The first windows' alternation, in 15-epoch windows: many windows to check one by one."""
    cfg, data, wls, ref = _load(d, measurements, **{"stls.window": 15})
    T = data.time_gps_s.size
    solved = (wls.status == "ok") & np.isfinite(wls.x_ecef_m).all(axis=1)
    status = wls.status.astype("<U24").copy()
    segs, jobs = _schedule(data, wls, solved, status, cfg.stls, None, 1.5)
    fits = fit_all(segs, jobs, cfg.stls)
    kinds = frozenset(measurements.split(","))
    out, runs, factors = alternate_windows(data, wls, cfg, segs, jobs, fits, kinds)
    assert T and runs
    return cfg, data, wls, segs, jobs, out, runs, factors, kinds


@pytest.mark.parametrize("measurements", ["pseudorange", "pseudorange,doppler"])
def test_alternation_misfit_never_rises_and_is_that_of_the_returned_kernel(noisy: Path, measurements: str) -> None:
    """Every window's misfit history is non-increasing; the misfit in its record equals the misfit
    recomputed from the returned trajectory (rows linearized there, clocks and drifts eliminated,
    velocities from the returned kernel's modes) to 1e-9, and the trajectory is in the returned
    kernel's behavior."""
    cfg, data, wls, segs, jobs, fits, runs, factors, kinds = _alternated(noisy, measurements)
    if wls.excluded is not None:
        data = replace(data, usable=data.usable & ~wls.excluded)
    fix = (wls.status == "ok") & np.isfinite(wls.x_ecef_m).all(axis=1)
    base = nominal_trajectory(data.time_gps_s, np.where(fix[:, None], wls.x_ecef_m, np.nan))
    checked = 0
    for run in runs:
        for b, k in enumerate(run.jobs):
            h = np.asarray(run.history[b])
            assert np.all(np.diff(h) <= 1e-10 * np.abs(h[:-1])), h
            fit = fits[k]
            if not run.converged[b] or run.failed[b]:
                assert "position-domain result kept" in fit.message
                continue
            assert fit.iterations == run.iterations[b] and fit.converged
            seg = segs[jobs[k].segment]
            ep = run.epochs[b]
            x = seg.origin + fit.w_hat @ seg.rot  # ENU -> ECEF
            r = np.asarray(fit.kernel.shared_coefficients)
            # the trajectory lies in the kernel's behavior: r(z) annihilates every coordinate
            e = sum(r[i] * fit.w_hat[i : len(ep) - 3 + i] for i in range(4))
            assert np.abs(e).max() <= 1e-9 * np.abs(fit.w_hat).max()
            nominal = base.copy()
            nominal[ep] = x
            rows = measurement_rows(data, nominal, cfg, "doppler" in kinds)
            pr = reduce_epochs(rows["P"][ep], rows["w"][ep] * run.mult[0, b] / factors[0], rows["y"][ep], rows["C"][ep])
            misfit = pr.s.sum()
            if "doppler" in kinds:
                y, yv, ok, has_v = shared_modes(r[None], len(ep), run.dt_s[b : b + 1])
                c = np.linalg.lstsq(y[0], x - seg.origin, rcond=None)[0]
                v = yv[0] @ c
                rr = reduce_epochs(rows["H"][ep], rows["wd"][ep] * run.mult[1, b] / factors[1], rows["yd"][ep])
                misfit += rr.s.sum() - 2 * np.sum(v * rr.r) + np.einsum("ti,tij,tj->", v, rr.M, v)
            assert fit.misfit == pytest.approx(misfit, rel=1e-9)
            checked += 1
    assert checked >= 5


def test_one_fixed_kernel_step_is_the_stacked_least_squares(noisy: Path) -> None:
    """Pseudoranges alone, one step from a fixed kernel: the window's trajectory equals the
    independent stacked weighted least squares over [O-basis positions, per-epoch clocks]
    (``O`` from :func:`~gnss_cli.behavior.multi_epoch.behavior_basis`)."""
    cfg, data, wls, ref = _load(noisy, "pseudorange")
    ep = np.arange(20, 35)
    n_t = ep.size
    dt = float(np.median(np.diff(data.time_gps_s[ep])))
    theta = 0.02
    r = np.real(np.poly([1.0, np.exp(1j * theta), np.exp(-1j * theta)]))[::-1]  # a turn at 0.02 rad per epoch
    origin = wls.x_ecef_m[ep[0]]
    nominal = wls.x_ecef_m.copy()
    rows = measurement_rows(data, nominal, cfg, False)
    P, w, yv_, C = rows["P"][ep], rows["w"][ep], rows["y"][ep], rows["C"][ep]
    d = nominal[ep] - origin

    y, _, ok, _ = shared_modes(r[None], n_t, np.array([dt]), velocity=False)
    assert ok[0]
    c, _, solved = solve_in_behavior(y, None, d[None], reduce_epochs(P, w, yv_, C))
    assert solved[0]
    x_step = origin + np.einsum("tj,ja->ta", y[0], c[0])

    # independent: rows y_ti = P_ti . (O_t g - d_t) + C_ti b_t, unknowns [g, b_1 ... b_N]
    O = behavior_basis(KernelRepresentation(np.kron(r, np.eye(3)), q=3), n_t)  # (N, 3, k)
    k, n_clk = O.shape[2], C.shape[2]
    used = w > 0
    n_rows = int(used.sum())
    A = np.zeros((n_rows, k + n_t * n_clk))
    rhs = np.zeros(n_rows)
    sw = np.zeros(n_rows)
    i = 0
    for t in range(n_t):
        for s in np.flatnonzero(used[t]):
            A[i, :k] = P[t, s] @ O[t]
            A[i, k + t * n_clk : k + (t + 1) * n_clk] = C[t, s]
            rhs[i] = yv_[t, s] + P[t, s] @ d[t]
            sw[i] = np.sqrt(w[t, s])
            i += 1
    keep = np.any(A[:, k:] != 0, axis=0)  # clocks without rows are not estimated
    A = np.hstack([A[:, :k], A[:, k:][:, keep]])
    sol = np.linalg.lstsq(A * sw[:, None], rhs * sw, rcond=None)[0]
    x_stacked = origin + np.einsum("tak,k->ta", O, sol[:k])
    np.testing.assert_allclose(x_step, x_stacked, rtol=0, atol=1e-6)


def test_settings_name_the_measurements_used(noisy: Path) -> None:
    cfg = load_config(None, {**BASE, "measurements": "pseudorange,doppler"})
    s = method_settings(cfg, has_doppler=True, has_phase=False)["stls"]
    assert s.estimator == "identified Hankel STLS (measurement domain, alternation)"
    assert s.measurements == "pseudorange+doppler"
    assert method_settings(replace(cfg, measurements=("pseudorange",)), True, False)["stls"].measurements == "pseudorange"


def test_lag_one_is_the_static_kernel_without_an_identification(noisy: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With ``--lag 1`` the shared kernel's root at 1 is the whole kernel, ``z - 1``: the windows
    are solved in it without running the identification (whose dense window projection took a
    whole-day ``--window 0`` run to 12 GB), and every window's record holds exactly ``[-1, 1]``."""
    import gnss_cli.pipeline.identified as identified

    def refuse(*args, **kwargs):  # type: ignore[no-untyped-def]
        raise AssertionError("lag 1 needs no identification")

    monkeypatch.setattr(identified, "identify_windows", refuse)
    cfg, data, wls, _ = _load(noisy, "pseudorange")
    cfg = replace(cfg, stls=replace(cfg.stls, lag=1, window=0))
    sol, models = solve_multi_epoch("stls", data, wls, cfg)
    assert models and all(np.array_equal(np.asarray(m.kernel.shared_coefficients), [-1.0, 1.0]) for m in models
                          if m.kernel is not None)
    assert np.isfinite(sol.x_ecef_m[sol.status == "ok"]).all() and (sol.status == "ok").sum() > 0


def _one_pseudorange_off(d: Path, cfg):  # type: ignore[no-untyped-def]
    """The flight's epochs, and the same with +200 m on the first usable pseudorange of epoch 60."""
    data = load_epochs(d / "obs.rnx", [d / "nav.rnx"], cfg)
    t = 60
    j = int(np.flatnonzero(data.usable[t])[0])
    pr = data.pr_corrected_m.copy()
    pr[t, j] += 200.0
    return data, replace(data, pr_corrected_m=pr), t, j


def test_an_epoch_whose_wls_fix_fails_its_test_does_not_cut_the_segment(noisy: Path) -> None:
    """``smoother`` and ``kf`` take an epoch whose WLS fix failed its test (through their gates);
    so does ``stls``: +200 m on one pseudorange at one epoch (``check``: WLS keeps the pulled fix,
    ``integrity_fail``) leaves one segment of windows, and the identified trajectory there, its
    gate leaving the faulty row out, is as close to the truth as at the other epochs."""
    cfg = load_config(None, {**BASE, "measurements": "pseudorange", "integrity": "check"})
    data, biased, t, j = _one_pseudorange_off(noisy, cfg)
    truth = np.asarray(reference_from_csv(noisy / "truth.csv", data.time_gps_s))
    wls = solve_method(biased, "wls", cfg)
    assert wls.status[t] == "integrity_fail" and np.linalg.norm(wls.x_ecef_m[t] - truth[t]) > 20.0
    sol, models = solve_multi_epoch("stls", biased, wls, cfg)
    assert {m.segment for m in models} == {0}
    err = np.linalg.norm(sol.x_ecef_m - truth, axis=1)
    assert sol.status[t] == "ok" and err[t] < 3.0 * _rms(np.delete(sol.x_ecef_m, t, axis=0), np.delete(truth, t, axis=0))


def test_clocks_and_residuals_are_of_the_satellites_wls_kept(noisy: Path) -> None:
    """``stls`` re-estimates each epoch's clocks at its own positions from the pseudoranges WLS
    used: a satellite FDE excluded (+200 m at one epoch) has no residual there, and every system's
    residuals have a zero weighted mean (the clock's least-squares condition). With the excluded
    row in the clock, every residual of its system would move by its share of the 200 m."""
    cfg = load_config(None, {**BASE, "measurements": "pseudorange"})
    data, biased, t, j = _one_pseudorange_off(noisy, cfg)
    wls = solve_method(biased, "wls", cfg)
    assert wls.excluded[t, j]
    sol, _ = solve_multi_epoch("stls", biased, wls, cfg)
    assert np.isnan(sol.residuals_m[t, j])
    used = np.isfinite(sol.residuals_m)
    w = np.where(used, 1.0 / np.where(used, wls.sigma_m, 1.0) ** 2, 0.0)
    for k in range(len(data.systems)):
        cols = data.system_index == k
        mean = (w[:, cols] * np.nan_to_num(sol.residuals_m[:, cols])).sum(axis=1) / np.maximum(w[:, cols].sum(axis=1), 1e-300)
        assert np.abs(mean[used[:, cols].any(axis=1)]).max() < 1e-6
    assert np.nanmax(np.abs(sol.residuals_m[t])) < 10.0


def test_with_range_rates_no_window_loses_them_to_a_kernel_without_velocity(noisy: Path,
                                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """An identified kernel with a root on the negative real axis has no velocity: its window could
    not use the range rates and kept its position-domain result. With the root moved to ``z = 1``
    (:func:`~gnss_cli.behavior.behavior_solve.sampled_motion_kernels`) no window is left so, and the
    spans' own trajectories (before the joint solve of :mod:`gnss_cli.pipeline.tied`, where a
    kernel without velocity takes difference quotients) are closer to the truth than with those
    windows left out of the measurement domain."""
    import gnss_cli.pipeline.identified as identified
    import gnss_cli.pipeline.tied as tied

    monkeypatch.setattr(tied, "tie_spans", lambda data, wls, config, segs, jobs, fits, *rest: (
        fits, np.zeros(data.usable.shape, dtype=bool), np.zeros(data.time_gps_s.size, dtype=bool),
        np.full((data.time_gps_s.size, 3), np.nan)))
    cfg, data, wls, truth = _load(noisy, "pseudorange,doppler")

    def lost(models) -> int:  # type: ignore[no-untyped-def]
        return sum("no kernel with a velocity" in m.message for m in models)

    sol, models = solve_multi_epoch("stls", data, wls, cfg)
    assert lost(models) == 0 and any("moved to z = 1" in m.message for m in models)
    monkeypatch.setattr(identified, "sampled_motion_kernels", lambda r: (r, np.zeros(r.shape[0], dtype=bool)))
    before, models_before = solve_multi_epoch("stls", data, wls, cfg)
    assert lost(models_before) > 0
    assert _rms(sol.x_ecef_m, truth) < _rms(before.x_ecef_m, truth)
