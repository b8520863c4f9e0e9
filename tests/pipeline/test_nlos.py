"""The NLOS detector (``[nlos] detector = "arcs"``, off by default; :mod:`gnss_cli.pipeline.nlos`): its parts on
hand-made arrays, and the WLS exclusions it makes against the simulator's LOS/NLOS labels, on
open sky, and for a bias injected over a known span; and the multi-epoch methods' reflection
spans (``[nlos] multi_epoch``, on by default) alike."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gnss_cli.config import load_config
from gnss_cli.errors import ConfigError
from gnss_cli.gnss.time import gps_s2week_tow
from gnss_cli.pipeline import load_epochs, process, solve_method
from gnss_cli.pipeline.methods import method_settings, solve_multi_epoch
from gnss_cli.pipeline.nlos import (code_minus_doppler_m, cusum_spans, doppler_span_delays_m, keep_redundancy,
                                    los_cn0_template_dbhz, persistent_spans, prediction_sigma_m, span_means,
                                    span_sigma_m)
from gnss_cli.sim.scenario import los_grid

ROOT = Path(__file__).resolve().parents[2]
ARCS = {"methods": "wls", "environment": "open", "nlos.detector": "arcs"}
OFF = {"methods": "wls", "environment": "open", "nlos.detector": "off"}
"""The detector alone, on or off: the open-sky settings otherwise (the default judges a canyon
urban, which turns the detector on with the levels over several satellites and min_direct_dof 1)."""


def _simulate(out: Path, *args: str) -> Path:
    from gnss_cli.cli.exits import run_app
    from gnss_cli.cli.simulate import app

    with pytest.raises(SystemExit) as done:
        run_app(app, "gnss-simulate", ["--trajectory", "drive", "--duration", "90", "--interval", "1",
                                       "--out-dir", str(out), "-q", *args])
    assert done.value.code == 0
    return out


@pytest.fixture(scope="module")
def canyon(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _simulate(tmp_path_factory.mktemp("nlos") / "canyon", "--environment", "urban", "--receiver", "dual",
                     "--seed", "201")


@pytest.fixture(scope="module")
def canyon_single(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _simulate(tmp_path_factory.mktemp("nlos") / "canyon1", "--environment", "urban", "--receiver", "single",
                     "--seed", "201")


@pytest.fixture(scope="module")
def open_sky(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _simulate(tmp_path_factory.mktemp("nlos") / "open", "--seed", "201")


def test_spans_are_runs_whose_score_reaches_the_threshold() -> None:
    active = np.array([[1, 1], [1, 0], [0, 1], [1, 1], [1, 1], [1, 1]], dtype=bool)
    score = np.array([[1.0, 5.0], [1.0, 0.0], [9.0, 1.0], [0.5, 1.0], [0.5, 1.0], [0.5, 1.0]])
    got = persistent_spans(active, score, 2.0)
    # column 0: runs [0, 1] (sum 2: a span) and [3, 5] (1.5: not); column 1: [0] (5) and [2, 5] (4)
    assert got[:, 0].tolist() == [True, True, False, False, False, False]
    assert got[:, 1].tolist() == [True, False, True, True, True, True]
    assert not persistent_spans(np.zeros((4, 2), bool), score[:4], 0.0).any()


def test_span_means_average_each_run() -> None:
    spans = np.array([[1, 0], [1, 1], [0, 0], [1, 1]], dtype=bool)
    values = np.array([[2.0, 9.0], [4.0, np.nan], [7.0, np.nan], [5.0, 1.0]])
    got = span_means(spans, values)
    np.testing.assert_array_equal(got[:, 0], [3.0, 3.0, np.nan, 5.0])
    np.testing.assert_array_equal(got[:, 1], [np.nan, np.nan, np.nan, 1.0])  # a run of NaNs has no mean


def test_the_prediction_sigma_is_the_spread_of_the_predicted_range() -> None:
    """:func:`prediction_sigma_m` against Monte Carlo: fixes drawn from the fix's covariance (two
    clocks, correlated) move the exact (non-linear) range to a left-out satellite of each system by
    that standard deviation."""
    from types import SimpleNamespace as NS

    rng = np.random.default_rng(5)
    x = np.array([4.0e6, 3.0e5, 4.9e6])
    sats = x + rng.normal(size=(1, 4, 3)) * 1.2e7 + 2.0e7 * x / np.linalg.norm(x)
    a = rng.normal(size=(5, 5)) * [3.0, 2.0, 5.0, 4.0, 1.0]
    cov = a @ a.T
    data = NS(sat_ecef_m=sats, clock_index=np.array([0, 1, 0, 1]), sv=np.array(["G01", "C02", "G03", "C04"]))
    which = np.array([[True, True, False, True]])
    got = prediction_sigma_m(data, NS(x_ecef_m=x[None], cov_m2=cov[None]), which)  # type: ignore[arg-type]
    draws = rng.multivariate_normal(np.zeros(5), cov, size=200_000)
    rng_0 = np.linalg.norm(sats[0] - x, axis=1)
    moved = np.linalg.norm(sats[0][None] - (x + draws[:, None, :3]), axis=2) - rng_0 + draws[:, 3 + data.clock_index]
    np.testing.assert_allclose(got[0, which[0]], moved.std(axis=0)[which[0]], rtol=0.01)
    assert np.isnan(got[0, 2])
    # a span's sigma: the predictions' variance stays, the pseudoranges' own is divided by its epochs
    spans = np.array([[True], [True], [True], [False]])
    s = span_sigma_m(spans, np.array([[1.0], [2.0], [2.0], [5.0]]), np.full((4, 1), 3.0))
    np.testing.assert_allclose(s[:3, 0], np.sqrt(3.0 + 9.0 / 3))
    assert np.isnan(s[3, 0])


def test_the_template_is_an_upper_quantile_per_bin_and_satellite_level() -> None:
    """Two satellites of one system climbing through the bins: the line-of-sight level follows
    the 0.9 quantile of each bin, a satellite 10 dB weaker all through keeps its own level, and
    its 10 dB drop over part of its track stands out against that level."""
    rng = np.random.default_rng(1)
    T = 400
    el = np.stack([np.linspace(10, 80, T), np.linspace(15, 85, T)], axis=1)
    los = 30.0 + 15.0 * np.sin(np.radians(el))
    snr = los + rng.normal(0.0, 0.3, el.shape)
    snr[:, 1] -= 10.0  # a weaker satellite (transmit power)
    snr[100:140, 1] -= 10.0  # and a reflection
    snr[200:230, 0] -= 12.0
    t = los_cn0_template_dbhz(snr, el, np.array([0, 0]), bin_deg=10.0, quantile=0.9, min_count=10)
    deficit = t - snr
    quiet0 = np.ones(T, bool)
    quiet0[200:230] = False
    quiet1 = np.ones(T, bool)
    quiet1[100:140] = False
    assert np.all(np.abs(deficit[quiet0, 0]) < 2.5) and np.all(np.abs(deficit[quiet1, 1]) < 2.5)
    assert np.all(deficit[200:230, 0] > 9.0) and np.all(deficit[100:140, 1] > 7.0)
    # a group without enough values has no template
    assert np.isnan(los_cn0_template_dbhz(snr[:5], el[:5], np.array([0, 1]), min_count=10)).all()


def test_an_epoch_keeps_its_redundancy_most_suspicious_out_first() -> None:
    used = np.ones((2, 7), dtype=bool)
    flagged = np.array([[1, 1, 1, 0, 0, 0, 0], [1, 0, 0, 0, 0, 0, 1]], dtype=bool)
    suspicion = np.array([[1.0, 3.0, 2.0, 0, 0, 0, 0], [5.0, 0, 0, 0, 0, 0, 1.0]])
    one_system = np.zeros(7, dtype=np.int64)
    # 7 satellites, one clock: min_dof 1 lets 2 go (dof 3 -> 1), the two most suspicious
    got = keep_redundancy(flagged, suspicion, used, one_system, 1, min_dof=1, min_satellites=4)
    assert got[0].tolist() == [False, True, True, False, False, False, False]
    assert got[1].tolist() == [True, False, False, False, False, False, True]
    # satellite 6 alone in a second system: dropping it also drops that clock, so dof does not fall
    two_systems = np.array([0, 0, 0, 0, 0, 0, 1])
    got = keep_redundancy(flagged, suspicion, used, two_systems, 2, min_dof=1, min_satellites=4)
    assert got[1].tolist() == [True, False, False, False, False, False, True]
    assert not keep_redundancy(flagged, suspicion, used, one_system, 1, min_dof=3, min_satellites=4).any()


def _labels(res, faults: pd.DataFrame) -> np.ndarray:  # noqa: ANN001 - RunResult
    """``(T, n)``: 1 LOS, 0 NLOS, -1 no label, from the simulator's faults.csv."""
    return los_grid(faults, res.epochs.time_gps_s, res.epochs.sv)


def test_the_canyon_reflections_are_excluded_and_the_direct_signals_kept(canyon: Path) -> None:
    """Against the simulator's labels, of the satellite-epochs WLS used or excluded: most NLOS
    out (the redundancy guard keeps the rest), almost every LOS in; without the detector, few."""
    labels = _labels(process(canyon / "obs.rnx", [canyon / "nav.rnx"], load_config(None, OFF)),
                     pd.read_csv(canyon / "faults.csv"))
    shares = {}
    for name, over in (("off", OFF), ("arcs", ARCS)):
        sol = process(canyon / "obs.rnx", [canyon / "nav.rnx"], load_config(None, over)).solutions["wls"]
        cand = np.isfinite(sol.residuals_m) | sol.excluded
        shares[name] = [float(sol.excluded[cand & (labels == v)].mean()) for v in (0, 1)]
    assert (labels == 0).sum() > 500  # a canyon: hundreds of reflected satellite-epochs
    assert shares["arcs"][0] > 0.75 and shares["arcs"][1] < 0.02
    assert shares["off"][0] < 0.3


def test_the_delay_test_keeps_only_spans_the_fix_predicts_short(canyon: Path) -> None:
    """``cn0_min_delay_m``: of the C/N0 spans, those whose pseudoranges the fix without them
    predicts short by that much (a reflection's extra path) stay out. The simulator's reflections
    are late by metres: with 2 m almost all stay out; with 10 km none does."""
    def excluded(**over: object) -> np.ndarray:
        cfg = load_config(None, {**ARCS, "integrity": "check", "nlos.failed_epochs": "keep", **over})
        return process(canyon / "obs.rnx", [canyon / "nav.rnx"], cfg).solutions["wls"].excluded

    every, late = excluded(**{"nlos.cn0_min_delay_m": -np.inf}), excluded(**{"nlos.cn0_min_delay_m": 2.0})
    assert every.sum() > 300 and not (late & ~every).any() and late.sum() >= 0.9 * every.sum()
    assert not excluded(**{"nlos.cn0_min_delay_m": 1e4}).any()


def test_uncertain_delays_down_weight_what_the_fix_cannot_call_early(canyon: Path) -> None:
    """``cn0_delay_sigmas``: a C/N0 span whose fix-measured delay is short of the threshold but within
    that many standard deviations of it is down-weighted, not kept at full weight; the spans that are
    surely late are excluded as before. With a 10 m threshold (the canyon's reflections are late by
    5-40 m) more of the reflections are then out or at a hundredth of their weight, and no more of
    the direct signals."""
    def run(z: float):  # noqa: ANN202
        cfg = load_config(None, {**ARCS, "integrity": "check", "nlos.failed_epochs": "keep",
                                 "nlos.cn0_min_delay_m": 10.0, "nlos.cn0_delay_sigmas": z})
        res = process(canyon / "obs.rnx", [canyon / "nav.rnx"], cfg)
        return res.solutions["wls"], res.epochs

    (plain, epochs), (wide, _) = run(0.0), run(2.0)
    np.testing.assert_array_equal(plain.excluded, wide.excluded)  # the same fix measures the same delays
    low = lambda sol: np.nan_to_num(sol.variance_scale, nan=1.0) > 1.0 if sol.variance_scale is not None else False  # noqa: E731
    assert (low(wide) & ~low(plain)).sum() > 20 and not (low(plain) & ~low(wide)).any()
    labels = los_grid(pd.read_csv(canyon / "faults.csv"), epochs.time_gps_s, epochs.sv)
    out = {z: sol.excluded | low(sol) for z, sol in (("plain", plain), ("wide", wide))}
    assert out["wide"][labels == 0].mean() > out["plain"][labels == 0].mean()
    assert out["wide"][labels == 1].sum() == out["plain"][labels == 1].sum()


def test_open_sky_and_clean_files_lose_no_satellite(open_sky: Path, rinex_dir: Path) -> None:
    """Clean C/N0 (the simulator's open sky, the sample file, a geodetic station's 17 minutes):
    nothing is flagged, and the fixes are those without the detector, bit for bit."""
    files = [(open_sky / "obs.rnx", [open_sky / "nav.rnx"]),
             (ROOT / "sample_rinex" / "static" / "obs.rnx", [ROOT / "sample_rinex" / "static" / "nav.rnx"]),
             (rinex_dir / "p433-2019" / "P43300USA_R_20190012056_17M_15S_MO.crx", [rinex_dir / "p433-2019" / "brdc0010.19n"])]
    for obs, navs in files:
        on = process(obs, navs, load_config(None, ARCS))
        off = process(obs, navs, load_config(None, OFF))
        assert on.epochs.snr_dbhz is not None and np.isfinite(on.epochs.snr_dbhz).any(), obs
        assert not on.solutions["wls"].excluded.any(), obs
        np.testing.assert_array_equal(on.solutions["wls"].x_ecef_m, off.solutions["wls"].x_ecef_m)


def test_a_persistent_bias_is_excluded_over_its_span_only(open_sky: Path) -> None:
    """+20 m on one satellite for 15 s, its C/N0 untouched: the residual test excludes it from
    the first to the last biased epoch and nowhere else, and the fixes there are those without
    it. (``integrity = "check"``: no FDE, the exclusions are the detector's alone.)"""
    cfg = load_config(None, {**ARCS, "integrity": "check", "nlos.residual_k": 2.0, "nlos.residual_h": 10.0})
    data = load_epochs(open_sky / "obs.rnx", [open_sky / "nav.rnx"], cfg)
    span = np.zeros(data.usable.shape[0], dtype=bool)
    span[40:55] = True
    sigma = solve_method(data, "wls", cfg).sigma_m[span]
    j = int(np.argmin(np.where(np.isfinite(sigma).all(axis=0), np.nan_to_num(sigma).max(axis=0), np.inf)))
    assert data.usable[span, j].all()
    one = np.outer(span, np.arange(data.sv.size) == j)
    biased = replace(data, pr_corrected_m=data.pr_corrected_m + one * 20.0)
    sol = solve_method(biased, "wls", cfg)
    assert sol.excluded[:, j].tolist() == span.tolist()
    assert not np.delete(sol.excluded, j, axis=1).any()
    clean = solve_method(replace(data, usable=data.usable & ~one), "wls", cfg)
    np.testing.assert_allclose(sol.x_ecef_m, clean.x_ecef_m, atol=1e-6)
    # without the residual test (C/N0 only) the bias stays in, and pulls the fixes of its span
    no_cusum = load_config(None, {**ARCS, "integrity": "check"})
    kept = solve_method(biased, "wls", no_cusum)
    assert not kept.excluded.any()
    assert np.linalg.norm(kept.x_ecef_m[span] - clean.x_ecef_m[span], axis=1).min() > 1.0
    # integrity "off": the plain fix, no detector
    assert not solve_method(biased, "wls", replace(cfg, integrity="off")).excluded.any()


def test_the_doppler_tells_a_reflection_from_an_attenuated_direct_signal(open_sky: Path) -> None:
    """``cn0_delay_source = "doppler"``: two satellites 15 dB weak for 15 s, one of them 8 m late
    (a reflection), the other not (a direct signal through foliage), and a receiver clock jump of
    300 m inside the span. The code-minus-Doppler delays are 8 m and 0 (to the code noise averaged
    over the span), the late one is excluded over exactly its span and the weak direct one kept."""
    cfg = load_config(None, {**ARCS, "integrity": "check", "nlos.cn0_delay_source": "doppler",
                             "nlos.cn0_min_delay_m": 2.0})
    data = load_epochs(open_sky / "obs.rnx", [open_sky / "nav.rnx"], cfg)
    assert data.range_rate_m_s is not None and data.snr_dbhz is not None
    span = np.zeros(data.usable.shape[0], dtype=bool)
    span[40:55] = True
    sigma = solve_method(data, "wls", cfg).sigma_m
    j, k = np.argsort(np.where(np.isfinite(sigma[span]).all(axis=0), np.nan_to_num(sigma[span]).max(axis=0), np.inf))[:2]
    late, weak = (np.outer(span, np.arange(data.sv.size) == i) for i in (j, k))
    jump = np.arange(span.size)[:, None] >= 47
    faulty = replace(data, pr_corrected_m=data.pr_corrected_m + 8.0 * late + 300.0 * jump,
                     snr_dbhz=data.snr_dbhz - 15.0 * (late | weak))
    got = doppler_span_delays_m(faulty, late | weak, late | weak)
    assert abs(got[span, j][0] - 8.0) < 0.5 and abs(got[span, k][0]) < 0.5
    assert np.isnan(got[~(late | weak)]).all()
    level, _ = code_minus_doppler_m(faulty)
    np.testing.assert_allclose(level, code_minus_doppler_m(replace(faulty, pr_corrected_m=faulty.pr_corrected_m
                                                                   - 300.0 * jump))[0], atol=1e-6)
    sol = solve_method(faulty, "wls", cfg)
    assert sol.excluded[:, j].tolist() == span.tolist()
    assert not np.delete(sol.excluded, j, axis=1).any()
    by_fix = solve_method(faulty, "wls", replace(cfg, nlos=replace(cfg.nlos, cn0_delay_source="fix")))
    assert by_fix.excluded[span, j].all()  # the fix sees the lone reflection too: a canyon's many pull it


def test_reflections_redundancy_keeps_are_down_weighted_alike_in_every_method(canyon_single: Path) -> None:
    """With ``variance_factor`` the C/N0 spans an epoch's redundancy keeps are not left at full
    weight: their variance is multiplied by it. A single-frequency GPS + BeiDou canyon, with
    ``min_dof = 3`` so that redundancy binds: against the simulator's labels, NLOS satellite-epochs
    out or below 10 % of their weight rise, LOS ones stay below 2 %. The WLS sigmas are the plain
    ones times sqrt(factor) exactly there and nowhere else; the smoother and the kf weigh the same
    rows alike (their sigma_m: one variance factor per kind, no other change)."""
    canyon = canyon_single
    base = load_config(None, {**ARCS, "methods": "wls,smoother,kf", "nlos.min_dof": 3})
    res1 = process(canyon / "obs.rnx", [canyon / "nav.rnx"], replace(base, nlos=replace(base.nlos, variance_factor=1.0)))
    res = process(canyon / "obs.rnx", [canyon / "nav.rnx"], replace(base, nlos=replace(base.nlos, variance_factor=100.0)))
    labels = _labels(res, pd.read_csv(canyon / "faults.csv"))
    wls = res.solutions["wls"]
    assert res1.solutions["wls"].variance_scale is None and wls.variance_scale is not None
    scaled = wls.variance_scale > 1.0
    used = np.isfinite(wls.residuals_m)
    cand = used | wls.excluded
    out = wls.excluded | (scaled & used)
    assert (scaled & used).any()
    assert out[cand & (labels == 0)].mean() > 0.9 and out[cand & (labels == 1)].mean() < 0.02
    assert out[cand & (labels == 0)].mean() > res1.solutions["wls"].excluded[cand & (labels == 0)].mean() + 0.05
    plain = res1.solutions["wls"].sigma_m  # the model's sigmas, at nearly the same fixes
    same = used & np.isfinite(plain)
    np.testing.assert_allclose((wls.sigma_m / plain)[same & scaled], 10.0, rtol=1e-4)  # the fixes differ slightly
    np.testing.assert_allclose((wls.sigma_m / plain)[same & ~scaled], 1.0, rtol=1e-4)
    for m in ("smoother", "kf"):
        sig = res.solutions[m].sigma_m
        both = np.isfinite(sig) & used
        ratio = sig[both] / wls.sigma_m[both]
        np.testing.assert_allclose(ratio, ratio[0], rtol=1e-4)  # one variance factor for the kind, no other change


def test_fixes_that_rest_on_suspected_reflections_are_not_ok(canyon_single: Path) -> None:
    """``min_direct_dof``: an ``ok`` WLS epoch becomes ``nlos_dependent`` exactly where its
    satellites at full weight, counted one epoch at a time here, give fewer redundant measurements
    (n - 3 - their systems' clocks) than asked. Nothing else changes: every method's positions,
    every other status, and the multi-epoch methods (they start from its fix as from an ok one);
    tls carries the WLS word. Against the simulator's truth, the epochs it takes from ``ok`` are
    the worse ones of a single-frequency canyon."""
    canyon = canyon_single
    over = {**ARCS, "methods": "wls,tls,smoother,kf"}
    plain = process(canyon / "obs.rnx", [canyon / "nav.rnx"], load_config(None, over))
    res = process(canyon / "obs.rnx", [canyon / "nav.rnx"], load_config(None, {**over, "nlos.min_direct_dof": 3}))
    wls, before = res.solutions["wls"], plain.solutions["wls"]
    systems = np.array([s[0] for s in res.epochs.sv.astype(str)])
    dof = []
    for t in range(wls.status.size):  # the direct satellites of each epoch, one at a time
        direct = [j for j in range(systems.size) if np.isfinite(wls.residuals_m[t, j]) and not wls.excluded[t, j]
                  and (wls.variance_scale is None or not wls.variance_scale[t, j] > 1.0)]
        dof.append(len(direct) - 3 - len({systems[j] for j in direct}))
    weak = (before.status == "ok") & (np.array(dof) < 3)
    assert 0 < weak.sum() < (before.status == "ok").sum()
    np.testing.assert_array_equal(wls.status, np.where(weak, "nlos_dependent", before.status))
    assert (plain.solutions["tls"].status[weak] == "ok").any()
    assert not (res.solutions["tls"].status[weak] == "ok").any()
    np.testing.assert_array_equal(res.solutions["tls"].status[~weak], plain.solutions["tls"].status[~weak])
    for m in ("wls", "tls", "smoother", "kf"):
        np.testing.assert_array_equal(res.solutions[m].x_ecef_m, plain.solutions[m].x_ecef_m)
        np.testing.assert_array_equal(res.solutions[m].hpl_m, plain.solutions[m].hpl_m)
    for m in ("smoother", "kf"):
        np.testing.assert_array_equal(res.solutions[m].status, plain.solutions[m].status)
    truth = pd.read_csv(canyon / "truth.csv")
    tow = np.round(gps_s2week_tow(res.epochs.time_gps_s)[1], 3)
    ref = truth.set_index(truth["tow_s"].round(3)).loc[tow, ["x_m", "y_m", "z_m"]].to_numpy()
    err = np.linalg.norm(wls.x_ecef_m - ref, axis=1)
    assert np.sqrt(np.mean(err[wls.status == "ok"] ** 2)) < np.sqrt(np.mean(err[before.status == "ok"] ** 2))


def test_a_run_whose_fixes_all_rest_on_suspected_reflections_still_writes_them(canyon_single: Path) -> None:
    """``nlos_dependent`` fixes passed their test: a run with no ``ok`` epoch but those is not
    refused as unsolved (a direct redundancy no epoch reaches)."""
    over = {**ARCS, "nlos.min_direct_dof": 99}
    res = process(canyon_single / "obs.rnx", [canyon_single / "nav.rnx"], load_config(None, over))
    words = set(res.solutions["wls"].status.tolist())
    assert "ok" not in words and "nlos_dependent" in words
    assert np.isfinite(res.solutions["wls"].x_ecef_m[res.solutions["wls"].status == "nlos_dependent"]).all()


def test_the_command_line_says_no_epoch_is_ok_without_quoting_nan(canyon_single: Path, tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """gnss-solve with every fix ``nlos_dependent``: exit 0, the tables written, and the closing line
    says that none is ``ok`` instead of quoting the statistics of no epoch (NaN)."""
    from gnss_cli.cli.exits import run_app
    from gnss_cli.cli.solve import app

    cfg = tmp_path / "all.toml"
    cfg.write_text('[processing]\nenvironment = "open"\n[nlos]\ndetector = "arcs"\nmin_direct_dof = 99\n')
    with pytest.raises(SystemExit) as done:
        run_app(app, "gnss-solve", [str(canyon_single / "obs.rnx"), str(canyon_single / "nav.rnx"), "--config", str(cfg),
                                    "--reference-csv", str(canyon_single / "truth.csv"), "--out-dir", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert done.value.code == 0, err
    line = next(x for x in err.splitlines() if "wls: " in x and "epochs solved" in x)
    assert "wls: 0/" in line and "none ok" in line and "nan" not in line.lower()
    status = pd.read_csv(tmp_path / "o" / "positions.csv")["status"]
    assert "nlos_dependent" in set(status) and "ok" not in set(status)


@pytest.mark.parametrize(("key", "value", "match"), [
    ("nlos.detector", "cn0", "nlos.detector"), ("nlos.cn0_exit_db", 12.0, "exit <= enter"),
    ("nlos.residual_k", 0.0, "nlos.residual_k"), ("nlos.min_dof", 0, "nlos.min_dof"),
    ("nlos.template_quantile", 1.0, "nlos.template_quantile"), ("nlos.variance_factor", 0.5, "nlos.variance_factor"),
    ("nlos.multi_epoch", "cn0", "nlos.multi_epoch"), ("nlos.multi_epoch_h", 0.0, "nlos.multi_epoch_h"),
    ("nlos.multi_epoch_k", -1.0, "nlos.multi_epoch_k"), ("nlos.multi_epoch_rounds", 0, "nlos.multi_epoch_rounds"),
    ("nlos.cn0_delay_source", "carrier", "nlos.cn0_delay_source"), ("nlos.multi_epoch_min_dof", 0, "nlos.multi_epoch_min_dof"),
    ("nlos.cn0_delay_sigmas", -1.0, "nlos.cn0_delay_sigmas"), ("nlos.cn0_delay_sigmas", float("inf"), "nlos.cn0_delay_sigmas"),
    ("nlos.min_direct_dof", -1, "nlos.min_direct_dof")])
def test_bad_settings_are_refused_by_name(key: str, value: object, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        load_config(None, {key: value})


def test_summary_names_the_detector_only_when_it_runs() -> None:
    """summary.csv's integrity column: off by default, so the defaults write ``fde`` alone; on, the
    ls/wls rows say so (whether the spans' delays came from the Doppler, and their margin); with integrity off
    the detector does not run and is not named."""
    def integrity(doppler: bool = False, **over: object) -> str:
        return method_settings(load_config(None, {"methods": "wls", **over}), doppler, False)["wls"].integrity

    assert integrity() == "fde"
    assert integrity(**{"nlos.detector": "arcs"}) == "fde, nlos arcs (delay margin 1 sigma)"  # packaged margin
    plain = {"nlos.detector": "arcs", "nlos.cn0_delay_sigmas": 0.0}
    assert integrity(**plain) == "fde, nlos arcs"
    by_doppler = {**plain, "nlos.cn0_delay_source": "doppler"}
    assert integrity(True, **by_doppler) == "fde, nlos arcs (span delays from the Doppler)"
    assert integrity(False, **by_doppler) == "fde, nlos arcs"  # a file without Doppler: the fix's delays
    margin = {"nlos.detector": "arcs", "nlos.cn0_delay_sigmas": 1.5}
    assert integrity(**margin) == "fde, nlos arcs (delay margin 1.5 sigma)"
    assert integrity(True, **{**by_doppler, "nlos.cn0_delay_sigmas": 2.0}) == \
        "fde, nlos arcs (span delays from the Doppler, delay margin 2 sigma)"
    assert integrity(**margin, **{"nlos.cn0_min_delay_m": -np.inf}) == "fde, nlos arcs"  # no delay test
    assert integrity(**{"nlos.detector": "arcs", "integrity": "off"}) == "off"
    assert integrity(**plain, **{"nlos.min_direct_dof": 1}) == "fde, nlos arcs, min direct dof 1"
    assert integrity(**{"nlos.min_direct_dof": 1}) == "fde"  # the detector off: nothing to depend on


def _cusum_loop(u: np.ndarray, k: float, h: float) -> np.ndarray:
    """The CUSUM spans, one satellite and one epoch at a time (the definition, written out)."""
    out = np.zeros(u.shape, dtype=bool)
    for j in range(u.shape[1]):
        s, start, best, best_t = 0.0, 0, 0.0, 0
        for t in range(u.shape[0] + 1):
            x = u[t, j] if t < u.shape[0] else np.nan
            new = 0.0 if np.isnan(x) else max(0.0, s + x - k)
            if s == 0.0 and new > 0.0:
                start, best, best_t = t, new, t
            elif new > best:
                best, best_t = new, t
            if s > 0.0 and new == 0.0 and best >= h:
                out[start:best_t + 1, j] = True
            s = new
    return out


def test_cusum_spans_equal_the_definition_one_epoch_at_a_time() -> None:
    """The vectorized CUSUM spans equal a scalar loop, on noise with biased stretches and gaps."""
    rng = np.random.default_rng(5)
    u = rng.normal(size=(400, 12))
    u[50:90, 3] += 2.0
    u[200:230, 7] += 1.2
    u[rng.random(u.shape) < 0.05] = np.nan
    for k, h in ((0.5, 5.0), (1.0, 5.0), (0.0, 3.0)):
        got = cusum_spans(u, k, h)
        np.testing.assert_array_equal(got, _cusum_loop(u, k, h))
    spans = cusum_spans(u, 0.5, 5.0)
    assert spans[55:85, 3].mean() > 0.9 and spans[:, [0, 1, 2]].mean() < 0.05


def test_multi_epoch_spans_take_a_persistent_bias_out_of_the_smoother_and_kf(open_sky: Path) -> None:
    """A bias of 2.5 sigma on one satellite for 30 s, its C/N0 untouched, on open sky: too small
    for the gate at any one epoch, it pulls the smoother's and the kf's track; their reflection
    spans leave it out over (most of) its span and nowhere else, and the track is that without it."""
    cfg = load_config(None, {"methods": "wls,smoother,kf"})
    data = load_epochs(open_sky / "obs.rnx", [open_sky / "nav.rnx"], cfg)
    span = np.zeros(data.usable.shape[0], dtype=bool)
    span[30:60] = True
    wls = solve_method(data, "wls", cfg)
    sigma = np.where(data.usable[span].all(axis=0), np.nan_to_num(wls.sigma_m[span], nan=np.inf).max(axis=0), np.inf)
    j = int(np.argmin(sigma))
    one = np.outer(span, np.arange(data.sv.size) == j)
    biased = replace(data, pr_corrected_m=data.pr_corrected_m + one * 2.5 * sigma[j])
    off = replace(cfg, nlos=replace(cfg.nlos, multi_epoch="off"))
    wls_biased = solve_method(biased, "wls", cfg)
    without = replace(data, usable=data.usable & ~one)
    for m in ("smoother", "kf"):
        clean = solve_multi_epoch(m, data, wls, cfg)[0]
        on, pulled = (solve_multi_epoch(m, biased, wls_biased, c)[0] for c in (cfg, off))
        spans = on.excluded & ~(pulled.excluded | clean.excluded)  # the smoother's gate excludes rows of its own
        assert on.excluded[span, j].all(), m
        assert spans[~span, j].sum() <= 2 and not np.delete(spans, j, axis=1).any(), m
        # the track is the one solved without the satellite over the span; without the spans it is pulled
        alone = solve_multi_epoch(m, without, solve_method(without, "wls", cfg), off)[0]
        moved_on = np.linalg.norm(on.x_ecef_m - alone.x_ecef_m, axis=1).max()
        moved_off = np.linalg.norm(pulled.x_ecef_m - alone.x_ecef_m, axis=1).max()
        assert moved_off > 1.0 and moved_on < 0.1 * moved_off, (m, moved_on, moved_off)


def test_multi_epoch_spans_take_the_canyon_reflections_out(canyon_single: Path) -> None:
    """Against the simulator's labels, on a single-frequency canyon drive: the smoother's and the
    kf's reflection spans leave out most NLOS satellite-epochs the methods were given and few LOS
    ones, and their 3D error over every epoch falls. WLS is the same with or without them."""
    obs, navs = canyon_single / "obs.rnx", [canyon_single / "nav.rnx"]
    truth = pd.read_csv(canyon_single / "truth.csv")[["x_m", "y_m", "z_m"]].to_numpy()
    over = {"methods": "wls,smoother,kf", "environment": "open"}  # WLS without the NLOS detector
    on = process(obs, navs, load_config(None, over))
    off = process(obs, navs, load_config(None, {**over, "nlos.multi_epoch": "off"}))
    labels = _labels(on, pd.read_csv(canyon_single / "faults.csv"))
    wls = on.solutions["wls"]
    np.testing.assert_array_equal(wls.x_ecef_m, off.solutions["wls"].x_ecef_m)
    given = np.isfinite(wls.residuals_m)  # what WLS used: the methods' pseudoranges before their own tests
    for m in ("smoother", "kf"):
        out_on, out_off = (r.solutions[m].excluded & given for r in (on, off))
        err = [np.sqrt(np.mean(np.sum((r.solutions[m].x_ecef_m - truth) ** 2, axis=1))) for r in (on, off)]
        assert out_on[labels == 0].mean() > out_off[labels == 0].mean() + 0.15, m
        assert out_on[labels == 1].mean() < 0.05, m
        assert err[0] < 0.8 * err[1], (m, err)


def test_settings_name_the_reflection_spans_where_they_run() -> None:
    def integrity(m: str, **over: object) -> str:
        return method_settings(load_config(None, {"methods": m, **over}), True, False)[m].integrity

    assert integrity("smoother") == "residual gate, check, reflection spans, segment misfit 5"
    assert integrity("kf", **{"nlos.multi_epoch": "off", "max_segment_misfit": float("inf")}) == "innovation gate, check"
    assert integrity("stls", **{"stls.lag": 3}) == "check, reflection spans"
    assert integrity("smoother", integrity="off") == "off"


def test_summary_settings_record_the_spans_with_a_multi_epoch_method() -> None:
    """``summary.csv``'s ``nlos`` setting: the detector, and the multi-epoch spans where a method
    has them (no ``;``: the settings column is ``key=value`` pairs joined by ``; ``)."""
    from gnss_cli.cli.tables import run_settings

    def nlos(**over: object) -> str:
        return run_settings(load_config(None, over), "")["nlos"]

    assert nlos(methods="wls") == "off"
    assert nlos(methods="wls,kf") == "off, multi-epoch spans cusum k 1.5 h 5 x3"
    assert nlos(methods="wls,kf", **{"nlos.multi_epoch": "off"}) == "off"
    assert nlos(methods="smoother", integrity="off") == "off"
    assert ";" not in nlos(methods="smoother", **{"nlos.detector": "arcs"})
