"""The kernel descent on the measurement misfit (:func:`gnss_cli.pipeline.identified._descend`) and
the windows tied into one trajectory (:mod:`gnss_cli.pipeline.tied`), on a track the lag-3 model
class holds (a constant-speed semicircle with 1 m code noise and range rates)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import gnss_cli.pipeline.identified as identified
import gnss_cli.pipeline.tied as tied
from gnss_cli.config import load_config
from gnss_cli.io.reference import reference_from_csv
from gnss_cli.pipeline import load_epochs, solve_method
from gnss_cli.pipeline.behavioral import Fit, WindowJob, _schedule, fit_all
from gnss_cli.pipeline.kalman import nominal_trajectory
from gnss_cli.pipeline.methods import solve_multi_epoch
from gnss_cli.sim.error_sources import parse_error_list
from gnss_cli.sim.scenario import ScenarioConfig, run_scenario, write_scenario

BASE = {"methods": "wls,stls,smoother", "stls.lag": 3, "iono": "none", "tropo": "none",
        "measurements": "pseudorange,doppler"}


@pytest.fixture(scope="module")
def arc(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    base = ScenarioConfig()
    cfg = replace(base, trajectory="semicircle", duration_s=240.0, interval_s=1.0, seed=5,
                  errors=base.errors.with_sources(parse_error_list("noise")))
    out = tmp_path_factory.mktemp("arc")
    write_scenario(run_scenario(cfg), out)
    config = load_config(None, BASE)
    data = load_epochs(out / "obs.rnx", [out / "nav.rnx"], config)
    ref = np.asarray(reference_from_csv(out / "truth.csv", data.time_gps_s))
    return config, data, solve_method(data, "wls", config), ref, 240.0


def _rms(x: np.ndarray, ref: np.ndarray) -> float:
    e = np.linalg.norm(x - ref, axis=1)
    return float(np.sqrt(np.mean(e[np.isfinite(e)] ** 2)))


def test_kernel_coefficients_about_one_round_trip() -> None:
    r = np.array([np.real(np.poly([1.0, 0.99 + 0.01j, 0.99 - 0.01j]))[::-1],
                  np.real(np.poly([1.0, 0.9, 1.05]))[::-1] * -3.0])
    p = identified._params_of(r)
    np.testing.assert_allclose(identified._kernel_of(p), r / r[:, -1:], rtol=1e-12, atol=1e-15)
    # about z = 1 the two roots 0.99 +- 0.01i are q(z) = (z - 1)^2 + 0.02 (z - 1) + 0.0002
    np.testing.assert_allclose(p[0], [2e-4, 2e-2], rtol=1e-9)


def test_descent_reaches_the_misfit_of_the_true_kernel(arc) -> None:  # type: ignore[no-untyped-def]
    """After the alternation no window's measurement misfit exceeds that of the kernel the track
    was drawn from by more than the chi2(2) quantile of 1e-3 (the likelihood ratio of the kernel's
    two free coefficients: the two kernels are statistically alike); the kernels identified from
    the free fixes (steps (a) and (b) alone) were up to 1600 above it."""
    from scipy.stats import chi2

    config, data, wls, _, span_s = arc
    solved = (wls.status == "ok") & np.isfinite(wls.x_ecef_m).all(axis=1)
    segs, jobs = _schedule(data, wls, solved, wls.status.astype("<U24").copy(), config.stls, None, 1.5)
    kinds = frozenset({"pseudorange", "doppler"})
    fits, runs, factors = identified.alternate_windows(data, wls, config, segs, jobs, fit_all(segs, jobs, config.stls),
                                                       kinds)
    theta = np.pi / (span_s - 1.0)  # the semicircle's turn per 1 s epoch
    true = np.real(np.poly([1.0, np.exp(1j * theta), np.exp(-1j * theta)]))[::-1]
    fix = (wls.status == "ok") & np.isfinite(wls.x_ecef_m).all(axis=1)
    plain = replace(data, usable=data.usable & ~wls.excluded) if wls.excluded is not None else data
    base = nominal_trajectory(data.time_gps_s, np.where(fix[:, None], wls.x_ecef_m, np.nan))
    checked = 0
    for run in runs:
        good = run.converged & ~run.failed
        run.done = ~good
        colors = [identified._colors([(int(e[0]), int(e[-1]) + 1) for e in run.epochs])]
        rows = identified.window_rows(plain, config, kinds, base, [run], colors)[0]
        normals = identified._normals(rows, run.mult, factors)
        got = identified._solve(run.r, run, normals, {})[3]
        want = identified._solve(np.tile(true, (run.r.shape[0], 1)), run, normals, {})[3]
        assert np.all(got[good] - want[good] <= chi2.isf(1e-3, 2)), (got[good] - want[good]).max()
        checked += int(good.sum())
    assert checked >= 10


def test_tied_windows_carry_the_range_rates_along_the_run(arc, monkeypatch: pytest.MonkeyPatch) -> None:  # type: ignore[no-untyped-def]
    """Tied, the windows of a run share the pseudoranges of the whole run through the range
    rates: the 3D RMS falls below 0.6 x that of the windows solved alone and comes within 1.2 x
    of the fixed-model smoother's, which holds this track exactly."""
    config, data, wls, ref, _ = arc
    sol, models = solve_multi_epoch("stls", data, wls, config)
    smoother, _ = solve_multi_epoch("smoother", data, wls, config)
    assert any("tied to its neighbours" in m.message for m in models)
    monkeypatch.setattr(tied, "tie_spans", lambda data, config, factors, mult, segs, jobs, fits: fits)
    alone, models_alone = solve_multi_epoch("stls", data, wls, config)
    assert not any("tied" in m.message for m in models_alone)
    rms, rms_alone, rms_smoother = _rms(sol.x_ecef_m, ref), _rms(alone.x_ecef_m, ref), _rms(smoother.x_ecef_m, ref)
    assert rms <= 0.6 * rms_alone, (rms, rms_alone)
    assert rms <= 1.2 * rms_smoother, (rms, rms_smoother)


def test_ties_join_only_windows_that_agree() -> None:
    """Two windows of identity information whose positions at the tied epoch differ by 1 (3
    sigma-units in all) are tied at chi2(3) 1e-6; differing by 10 they are not."""
    lag = 3
    width = 3 * lag
    ties = np.zeros((3, 2 * width))
    for p in range(3):
        ties[p, p] = 1.0  # position of window 0 = its coefficient 0 of coordinate p
        ties[p, width + p] = -1.0
    blocks = [np.eye(width), np.eye(width)]
    for jump, want in ((1.0, True), (10.0, False)):
        rhs = [np.zeros(width), np.zeros(width)]
        rhs[1][:3] = jump / np.sqrt(3.0)
        assert tied._agreeing_ties(ties, blocks, rhs, 1e-6)[0] == want


def test_runs_break_where_windows_do_not_follow_or_differ_in_kinds() -> None:
    def fit(kinds: frozenset[str]) -> Fit:
        from gnss_cli.behavior.records import shared_kernel_records

        rec = shared_kernel_records(np.array([[-1.0, 3.0, -3.0, 1.0]]), 3)[0]
        return Fit(np.zeros((15, 3)), rec, 1.0, None, "", None, domain="measurement", kinds=kinds)

    pr, prd = frozenset({"pseudorange"}), frozenset({"pseudorange", "doppler"})
    jobs = [WindowJob(0, 0, 0, 15, 0, 11), WindowJob(0, 1, 7, 22, 11, 18), WindowJob(0, 2, 14, 29, 18, 25),
            WindowJob(0, 3, 21, 36, 25, 32), WindowJob(1, 0, 0, 15, 0, 11), WindowJob(1, 1, 7, 22, 12, 18)]
    fits = [fit(prd), fit(prd), fit(prd), fit(pr), fit(prd), fit(prd)]
    assert tied.chains(jobs, fits) == [[0, 1, 2]]
