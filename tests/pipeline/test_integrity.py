"""Integrity monitoring of the ls/wls fixes: chi-square test, FDE, protection levels, statuses
(README "Integrity"); measured on simulated random outliers and on real data."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gnss_cli.config import load_config
from gnss_cli.errors import ConfigError
from gnss_cli.gnss.time import gps_s2week_tow
from gnss_cli.pipeline import process
from gnss_cli.pipeline.epochs import load_epochs
from gnss_cli.pipeline.integrity import chi2_threshold
from gnss_cli.pipeline.snapshot import solve_method
from gnss_cli.sim.scenario import ScenarioConfig, config_from_mapping, run_scenario, write_scenario

REF_0759 = np.array([-3976219.1879, 3382371.6041, 3652511.1428])
TST_TRUTH = np.array([-2418077.2710, 5386069.6872, 2405174.1252])


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2)))


def test_thresholds_equal_scipy_stats_quantiles():
    """scipy.special's inverse against scipy.stats' distribution, for the default false-alarm
    probability over 1 ... 100 degrees of freedom and for others; none for dof 0."""
    from scipy.stats import chi2

    assert chi2_threshold(0, 1e-3) == np.inf
    for pfa, dofs in ((1e-3, range(1, 101)), (1e-2, (1, 2, 7, 40)), (1e-5, (1, 3, 150))):
        for dof in dofs:
            assert chi2_threshold(dof, pfa) == pytest.approx(float(chi2.isf(pfa, dof)), rel=1e-12), (pfa, dof)


def test_bad_integrity_settings_are_configuration_errors():
    for overrides in ({"integrity": "maybe"}, {"integrity_pfa": 0.0}, {"integrity_pmd": 1e-3}, {"max_gdop": -1.0},
                      {"exclude": "X99"},
                      {"alert_limit_h_m": 0.0}, {"fde_min_dof": 1}):
        with pytest.raises(ConfigError):
            load_config(None, overrides)
    assert load_config(None, {"exclude": "g7, C28"}).exclude == ("G07", "C28")


@pytest.fixture(scope="module")
def data_0759(rinex_dir):
    d = rinex_dir / "rtklib-0759"
    return load_epochs(d / "07590920.05o", [d / "07590920.05n"], load_config())


def _same_numbers(a: np.ndarray, b: np.ndarray) -> None:
    """Equal bits with numpy 2; with numpy 1.x, whose vectorized sums change their last bits with
    the arrays' memory alignment from one run to the next, equal to 1e-12 relative."""
    if int(np.__version__.split(".")[0]) >= 2:
        np.testing.assert_array_equal(a, b)
    else:
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=0)


def test_clean_0759_needs_no_exclusion_and_keeps_every_number(data_0759):
    cfg = load_config()
    fde = solve_method(data_0759, "wls", cfg)
    off = solve_method(data_0759, "wls", replace(cfg, integrity="off"))
    assert fde.excluded.sum() == 0 and (fde.status == "ok").all()
    _same_numbers(fde.x_ecef_m, off.x_ecef_m)
    _same_numbers(fde.gdop, off.gdop)
    assert np.isfinite(fde.test_stat).all() and np.isnan(off.test_stat).all()
    assert (fde.hpl_m > 0).all() and (fde.vpl_m > fde.hpl_m).mean() > 0.5


@pytest.mark.parametrize("bias", [50.0, 100.0, 200.0, 500.0])
def test_a_biased_satellite_is_excluded_and_the_fix_returns(data_0759, bias):
    cfg = load_config()
    clean = solve_method(data_0759, "wls", cfg)
    j = int(np.argmax(np.isfinite(clean.residuals_m).sum(axis=0)))
    rows = np.arange(40, 60)
    pr = data_0759.pr_corrected_m.copy()
    pr[rows, j] += bias
    bad = replace(data_0759, pr_corrected_m=pr)
    sol = solve_method(bad, "wls", cfg)
    assert sol.excluded[rows, j].all()
    assert sol.excluded.sum() == rows.size  # nothing else
    assert (sol.status == "ok").all()
    err = np.linalg.norm(sol.x_ecef_m[rows] - REF_0759, axis=1)
    err_clean = np.linalg.norm(clean.x_ecef_m[rows] - REF_0759, axis=1)
    assert _rms(err) < _rms(err_clean) + 0.5
    # the other methods take the WLS satellite set
    tls = solve_method(bad, "tls", cfg, linearization=sol)
    assert np.isnan(tls.residuals_m[rows, j]).all() and tls.excluded[rows, j].all()
    # the test alone flags the epochs and keeps their (wrong) numbers
    chk = solve_method(bad, "wls", replace(cfg, integrity="check"))
    assert (chk.status[rows] == "integrity_fail").all() and np.isfinite(chk.x_ecef_m[rows]).all()
    assert (chk.status[np.setdiff1d(np.arange(120), rows)] == "ok").all()


def test_gdop_limit_keeps_the_position(data_0759):
    sol = solve_method(data_0759, "wls", replace(load_config(), max_gdop=2.6))
    limited = sol.status == "gdop_limit"
    assert limited.any() and (sol.gdop[limited] > 2.6).all() and np.isfinite(sol.x_ecef_m[limited]).all()


def test_hpl_limit_keeps_the_position_and_only_protected_epochs_stay_ok(data_0759):
    cfg = load_config()
    sol = solve_method(data_0759, "wls", cfg)
    assert cfg.alert_limit_h_m == np.inf and (sol.status == "ok").all()  # off by default
    tight = solve_method(data_0759, "wls", replace(cfg, alert_limit_h_m=40.0))
    limited = tight.status == "hpl_limit"
    assert limited.any() and (tight.hpl_m[limited] > 40.0).all() and np.isfinite(tight.x_ecef_m[limited]).all()
    assert (tight.hpl_m[tight.status == "ok"] <= 40.0).all()
    _same_numbers(tight.x_ecef_m, sol.x_ecef_m)  # a status, not another position


def test_gps_alone_in_the_urban_canyon_is_mostly_unprotected(rinex_dir):
    """tst2 with the GPS file only (5-8 satellites, several reflected at once). Classic FDE
    (``fde_min_dof = 2``) excludes down to one degree of freedom, where a second fault cannot
    be seen: every epoch passes, 120 of them 100-200 m off. The default (3) keeps the test
    two degrees of freedom: fewer ``ok`` epochs, and those much closer to the truth. With a
    556 m alert limit the ``ok`` epochs are the protected ones. All with the open-sky settings
    (``environment = "open"``; the default judges this file a canyon). The NLOS detector (off
    there), which takes the weak signals out first and down-weights those an epoch's redundancy
    keeps, makes more epochs ``ok`` (78 % instead of 57 %), each inside its levels -- though not
    closer (40 m against 29 m; with the settings chosen before, 9/5 dB and ``min_dof`` 1, 74 % at
    30 m: with ``min_dof`` 2 it takes fewer satellites out of these 5-8-satellite epochs)."""
    d = rinex_dir / "tst2-2020155-urban-static"
    def solve(**overrides):
        res = process(d / "2020_06_03_TST_03.obs.gz", [d / "hksc155d.20n"], load_config(None, {"methods": "wls", "environment": "open", **overrides}))
        sol = res.solutions["wls"]
        return sol, np.linalg.norm(sol.x_ecef_m - TST_TRUTH, axis=1)

    classic, err_classic = solve(fde_min_dof=2)
    default, err = solve()
    ok_classic, ok = classic.status == "ok", default.status == "ok"
    detector, err_detector = solve(**{"nlos.detector": "arcs"})
    ok_detector = detector.status == "ok"
    assert ok_detector.mean() > ok.mean() + 0.1
    assert (err_detector[ok_detector] <= np.hypot(detector.hpl_m, detector.vpl_m)[ok_detector]).all()
    assert ok_classic.mean() > 0.95 and (err_classic[ok_classic] > 100.0).sum() > 50
    assert 0.2 < ok.mean() < 0.7 and (default.status[~ok] == "integrity_fail").all()
    assert _rms(err[ok]) < 0.7 * _rms(err_classic[ok_classic])
    assert (default.excluded.sum(axis=1)[ok] <= classic.excluded.sum(axis=1)[ok]).all()
    limited, _ = solve(alert_limit_h_m=556.0)
    hl = limited.status == "hpl_limit"
    assert hl.any() and (limited.hpl_m[hl] > 556.0).all() and (limited.hpl_m[limited.status == "ok"] <= 556.0).all()


@pytest.mark.parametrize("trajectory", ["static", "standard-flight"])
def test_random_simulated_outliers_are_found(tmp_path, trajectory):
    base = config_from_mapping({"simulate": {"trajectory": trajectory, "duration_s": 600.0, "seed": 2,
                                             "systems": "G,E", "errors": "all"}}, ScenarioConfig())
    runs = {}
    for name, rate in (("clean", 0.0), ("faulty", 0.05)):
        scen = run_scenario(replace(base, errors=replace(base.errors, outlier_rate=rate)))
        write_scenario(scen, tmp_path / name)
        res = process(tmp_path / name / "obs.rnx", [tmp_path / name / "nav.rnx"], load_config())
        runs[name] = (scen, res)
    scen, res = runs["faulty"]
    assert (tmp_path / "faulty" / "faults.csv").is_file() and not (tmp_path / "clean" / "faults.csv").exists()
    sol, sv = res.solutions["wls"], res.epochs.sv
    col = {s: i for i, s in enumerate(scen.observations.sv)}
    bias = scen.observations.outlier_bias_m[:, [col[s] for s in sv]]
    faulty = (bias != 0).any(axis=1)
    assert faulty.sum() >= 15
    assert (sol.excluded & (bias != 0)).any(axis=1)[faulty].mean() >= 0.99
    assert sol.excluded[~faulty].any(axis=1).mean() <= 0.01
    truth = scen.observations.rx_pos_ecef_m
    rms = {k: _rms(np.linalg.norm(r.solutions["wls"].x_ecef_m - truth, axis=1)) for k, (_, r) in runs.items()}
    assert rms["faulty"] <= 1.05 * rms["clean"]


def test_urban_static_tst_most_epochs_ok_and_close(rinex_dir):
    d = rinex_dir / "tst2-2020155-urban-static"
    navs = sorted(d.glob("hksc155d.20?"))
    out = {}
    for name, overrides in (("fde", {}), ("off", {"integrity": "off"}),
                            ("snr30", {"snr_mask_dbhz": 30.0, "environment": "open"})):
        res = process(d / "2020_06_03_TST_03.obs.gz", navs, load_config(None, overrides))
        sol = res.solutions["wls"]
        _, tow = gps_s2week_tow(res.epochs.time_gps_s)
        window = (tow >= 270149 - 0.01) & (tow <= 270305 + 0.01)
        assert window.sum() == 157
        ok = window & (sol.status == "ok")
        out[name] = (ok.sum() / window.sum(), _rms(np.linalg.norm(sol.x_ecef_m[ok] - TST_TRUTH, axis=1)))
    # the defaults judge tst2 a street canyon (the urban settings): 98.7 % ok at 3.9 m; with the
    # open-sky settings 90.4 % at 5.1 m; off: 63.5 m; rnx2rtkp: 9 epochs at 7.2 m; snr30 (open) 100 % at 4.1 m
    assert out["fde"][0] >= 0.9 and out["fde"][1] <= 15.0  # issue 25: >= 90 % of the truth epochs at <= 15 m
    assert out["snr30"][0] >= 0.9 and out["snr30"][1] < 6.0
