"""Robust (M-estimate) snapshot fixes, ``robust = "huber" | "cauchy"`` (README "Integrity"):
the same fix as scipy's robust least squares on the pseudorange model, a fault's pull bounded,
clean data unchanged, and the integrity test on the final residuals."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import least_squares

from gnss_cli.config import load_config
from gnss_cli.constants import C_M_S, OMEGA_E_RAD_S
from gnss_cli.errors import ConfigError
from gnss_cli.pipeline.epochs import load_epochs
from gnss_cli.pipeline.snapshot import solve_method
from gnss_cli.solvers.robust import m_estimator_rho, m_estimator_weights
from gnss_cli.sim.scenario import ScenarioConfig, config_from_mapping, run_scenario, write_scenario

FAULT_ROWS = np.arange(100, 160)
FAULT_M = 200.0


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """A static GPS receiver, 300 epochs at 1 s (white noise only), its truth, and the same
    epochs with 200 m on one satellite (seen throughout) in epochs 100-159."""
    cfg_sim = config_from_mapping({"simulate": {"trajectory": "static", "duration_s": 300.0, "seed": 11,
                                                "systems": "G", "errors": "noise"}}, ScenarioConfig())
    scen = run_scenario(cfg_sim)
    folder = tmp_path_factory.mktemp("robust")
    write_scenario(scen, folder)
    cfg = load_config(None, {"iono": "none", "tropo": "none", "integrity": "off"})
    data = load_epochs(folder / "obs.rnx", [folder / "nav.rnx"], cfg)
    truth = scen.observations.rx_pos_ecef_m[np.searchsorted(scen.observations.t_gps_s, data.time_gps_s)]
    seen = data.usable.sum(axis=0)
    j = int(np.argmax(seen))
    assert seen[j] == data.usable.shape[0]
    pr = data.pr_corrected_m.copy()
    pr[FAULT_ROWS, j] += FAULT_M
    return cfg, data, replace(data, pr_corrected_m=pr), truth, j


def _err(sol, truth):
    return np.linalg.norm(sol.x_ecef_m - truth, axis=1)


@pytest.mark.parametrize("estimator", ["huber", "cauchy"])
def test_robust_fix_solves_the_estimating_equations_and_minimizes_the_loss(simulated, estimator):
    """Epochs of the faulty block, u_i = (p_i - |s_i - x| - sagnac_i - b) / sigma_i with the run's
    final sigmas: the fix solves the estimating equations sum_i psi(u_i) [e_i, -1] / sigma_i = 0
    (the pipeline's design rows [-e, 1], as in RTKLIB without the ~1e-6 derivative of the Sagnac
    term), and scipy's least_squares with loss=estimator, f_scale = k / c (the same sum of rho(u))
    ends within 1e-4 m of it, with no smaller loss (scipy's
    relative cost test stops it 1e-7-5e-5 m early here, at gradients of 1e-6; the 1e-6 m comparison
    with scipy is on linear epochs, tests/solvers/test_robust.py)."""
    cfg, _, faulty, truth, _ = simulated
    cfg = replace(cfg, robust=estimator, robust_tolerance=1e-12, robust_max_iterations=500, convergence_m=1e-7)
    sol = solve_method(faulty, "wls", cfg)
    assert (sol.status == "ok").all()
    tuning = cfg.robust_huber_k if estimator == "huber" else cfg.robust_cauchy_c
    for t in FAULT_ROWS[::15]:
        used = np.isfinite(sol.residuals_m[t])
        s, p, sigma = faulty.sat_ecef_m[t, used], faulty.pr_corrected_m[t, used], sol.sigma_m[t, used]

        def residuals(z):  # z: offset from the true position (m: well scaled for scipy), clock (m)
            x, b = truth[t] + z[:3], z[3]
            sagnac = OMEGA_E_RAD_S / C_M_S * (s[:, 0] * x[1] - s[:, 1] * x[0])
            return (p - np.linalg.norm(s - x, axis=1) - sagnac - b) / sigma

        def jacobian(z):  # du/dz with the design rows: analytic, as finite differences of 2e7 m ranges are noisy
            x = truth[t] + z[:3]
            e = (s - x) / np.linalg.norm(s - x, axis=1)[:, None]
            return np.column_stack([e / sigma[:, None], -1.0 / sigma])

        def equations(z):
            u = residuals(z)
            return jacobian(z).T @ (m_estimator_weights(u, estimator, tuning) * u)

        ours = np.r_[sol.x_ecef_m[t] - truth[t], sol.clock_m[t]]
        assert np.abs(equations(ours)).max() < 1e-8  # 1/m: the 200 m fault alone contributes ~0.2
        ref = least_squares(residuals, np.array([30.0, -30.0, 30.0, 0.0]), jac=jacobian, loss=estimator,
                            f_scale=tuning, xtol=1e-15, ftol=1e-15, gtol=1e-15)
        assert np.linalg.norm(ours[:3] - ref.x[:3]) < 1e-4 and abs(ours[3] - ref.x[3]) < 1e-4
        loss = m_estimator_rho(residuals(ours), estimator, tuning).sum()
        assert loss <= m_estimator_rho(residuals(ref.x), estimator, tuning).sum() * (1 + 1e-7)  # Sagnac: 4e-11 relative


def test_a_200_m_fault_moves_the_robust_fix_far_less(simulated):
    cfg, clean_data, faulty, truth, j = simulated
    clean = _err(solve_method(clean_data, "wls", cfg), truth)[FAULT_ROWS]
    plain = _err(solve_method(faulty, "wls", cfg), truth)[FAULT_ROWS]
    huber = solve_method(faulty, "wls", replace(cfg, robust="huber"))
    cauchy = solve_method(faulty, "wls", replace(cfg, robust="cauchy"))
    e_h, e_c = _err(huber, truth)[FAULT_ROWS], _err(cauchy, truth)[FAULT_ROWS]
    # the plain fix follows the fault; Huber's influence is bounded (k sigma per satellite),
    # Cauchy's redescends: measured 80 / 6.0 / 3.1 m median here (clean: 2.9 m)
    assert np.median(plain) > 30.0
    assert np.median(e_h) < 0.25 * np.median(plain) and np.max(e_h) < 0.35 * np.min(plain)
    assert np.median(e_c) < np.median(clean) + 0.5
    # the faulty satellite has the smallest weight of its epoch, and only it is tiny
    assert (np.nanargmin(cauchy.robust_weights[FAULT_ROWS], axis=1) == j).all()
    assert (cauchy.robust_weights[FAULT_ROWS, j] < 0.01).all()
    others = np.delete(cauchy.robust_weights[FAULT_ROWS], j, axis=1)
    assert np.nanmin(others) > 0.5


def test_on_clean_data_the_robust_fix_is_the_wls_fix(simulated):
    cfg, data, _, truth, _ = simulated
    wls = solve_method(data, "wls", cfg)
    huber = solve_method(data, "wls", replace(cfg, robust="huber"))
    cauchy = solve_method(data, "wls", replace(cfg, robust="cauchy"))
    # the a-priori sigmas (5.8 m with iono = none) exceed the 1 m noise: Huber gives every
    # satellite weight 1 and the WLS fix; Cauchy's weights are 0.84-1 and move it by 0.34 m
    # at most (the errors are 3.4 m 3D RMS)
    assert (huber.robust_weights[np.isfinite(huber.robust_weights)] == 1.0).all()
    assert np.max(np.linalg.norm(huber.x_ecef_m - wls.x_ecef_m, axis=1)) < 1e-6
    assert np.max(np.linalg.norm(cauchy.x_ecef_m - wls.x_ecef_m, axis=1)) < 0.5
    rms = {k: float(np.sqrt(np.mean(_err(s, truth) ** 2))) for k, s in (("wls", wls), ("cauchy", cauchy))}
    assert abs(rms["cauchy"] - rms["wls"]) < 0.05 * rms["wls"]
    assert (huber.status == "ok").all() and (cauchy.status == "ok").all()


def test_integrity_tests_the_robust_residuals_and_fde_still_excludes(simulated):
    """The chi-square statistic of the final (reweighted) residuals with the a-priori sigmas:
    a fault the robust fit down-weights still fails the test (``check``), and ``fde`` excludes it."""
    cfg, data, faulty, truth, j = simulated
    check = solve_method(faulty, "wls", replace(cfg, robust="cauchy", integrity="check"))
    assert (check.status[FAULT_ROWS] == "integrity_fail").all()
    assert (np.delete(check.status, FAULT_ROWS) == "ok").mean() > 0.98
    u = check.residuals_m / check.sigma_m
    np.testing.assert_allclose(check.test_stat, np.nansum(u**2, axis=1), rtol=1e-6)
    fde = solve_method(faulty, "wls", replace(cfg, robust="huber", integrity="fde"))
    assert fde.excluded[FAULT_ROWS, j].all() and (fde.status[FAULT_ROWS] == "ok").all()
    assert np.isnan(fde.robust_weights[FAULT_ROWS, j]).all()  # excluded: not used, no weight
    clean = _err(solve_method(data, "wls", cfg), truth)[FAULT_ROWS]
    assert np.median(_err(fde, truth)[FAULT_ROWS]) < np.median(clean) + 1.0  # measured 3.2 m, clean 2.9 m


def test_ls_is_reweighted_too(simulated):
    cfg, _, faulty, truth, _ = simulated
    plain = _err(solve_method(faulty, "ls", cfg), truth)[FAULT_ROWS]
    robust = _err(solve_method(faulty, "ls", replace(cfg, robust="cauchy")), truth)[FAULT_ROWS]
    assert np.median(robust) < 0.1 * np.median(plain)


def test_robust_settings_are_validated():
    assert load_config().robust == "off"
    assert load_config(None, {"robust": "Huber"}).robust == "huber"
    for overrides in ({"robust": "tukey"}, {"robust_huber_k": 0.0}, {"robust_tolerance": -1.0},
                      {"robust_max_iterations": 0}):
        with pytest.raises(ConfigError):
            load_config(None, overrides)
