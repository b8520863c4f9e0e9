"""Spans chosen from the data for ``stls --lag L`` (:mod:`gnss_cli.pipeline.spans`): the behavior
test's statistic against an independent computation, its calibration on a track the model class
holds, the noise-free manoeuvring flight to 1 cm, the windows that take a rejected one's epochs, and
a window two of them share solved once."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gnss_cli.config import load_config
from gnss_cli.io.reference import reference_from_csv
from gnss_cli.pipeline import load_epochs, solve_method
from gnss_cli.pipeline.behavioral import WindowJob, _schedule, fit_all
from gnss_cli.pipeline.identified import alternate_windows
from gnss_cli.pipeline.kalman import nominal_trajectory
from gnss_cli.pipeline.measurements import measurement_rows
from gnss_cli.pipeline.methods import solve_multi_epoch
from gnss_cli.pipeline import spans
from gnss_cli.pipeline.spans import behavior_limit, split_window
from gnss_cli.sim.error_sources import parse_error_list
from gnss_cli.sim.scenario import ScenarioConfig, run_scenario, write_scenario

BASE = {"methods": "wls,stls", "stls.lag": 3, "iono": "none", "tropo": "none"}


def _simulate(out: Path, trajectory: str, errors: str, seed: int, duration_s: float) -> Path:
    base = ScenarioConfig()
    cfg = replace(base, trajectory=trajectory, duration_s=duration_s, interval_s=1.0, seed=seed,
                  errors=base.errors.with_sources(parse_error_list(errors)))
    write_scenario(run_scenario(cfg), out)
    return out


def _load(d: Path, measurements: str, **more: object):  # type: ignore[no-untyped-def]
    cfg = load_config(None, {**BASE, "measurements": measurements, **more})
    data = load_epochs(d / "obs.rnx", [d / "nav.rnx"], cfg)
    return cfg, data, solve_method(data, "wls", cfg), np.asarray(reference_from_csv(d / "truth.csv", data.time_gps_s))


@pytest.fixture(scope="module")
def noisy_arc(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A constant-speed semicircle with 1 m code noise: its track is in a lag-3 shared behavior."""
    return _simulate(tmp_path_factory.mktemp("arc"), "semicircle", "noise", 5, 300.0)


@pytest.fixture(scope="module")
def exact_flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A noise-free manoeuvring flight (path drawn from the seed): not in any one lag-3 behavior."""
    return _simulate(tmp_path_factory.mktemp("flight"), "flight", "none", 101, 180.0)


def test_statistic_is_the_misfit_given_up_against_free_epochs(noisy_arc: Path) -> None:
    """Pseudoranges alone: each window's statistic equals its behavior misfit minus the sum of the
    epochs' own weighted least-squares misfits (position and clocks free, an independent ``lstsq``
    of the same rows linearized at the result), and its degrees of freedom are ``3 N - 3 l - (l - 1)``."""
    cfg, data, wls, _ = _load(noisy_arc, "pseudorange", **{"stls.window": 15})  # many windows to check
    solved = (wls.status == "ok") & np.isfinite(wls.x_ecef_m).all(axis=1)
    segs, jobs = _schedule(data, wls, solved, wls.status.astype("<U24").copy(), cfg.stls, None, 1.5)
    fits, runs, factors = alternate_windows(data, wls, cfg, segs, jobs, fit_all(segs, jobs, cfg.stls),
                                            frozenset({"pseudorange"}))
    if wls.excluded is not None:
        data = replace(data, usable=data.usable & ~wls.excluded)
    base = nominal_trajectory(data.time_gps_s, np.where(solved[:, None], wls.x_ecef_m, np.nan))
    checked = 0
    for run in runs:
        for b, k in enumerate(run.jobs):
            fit = fits[k]
            if fit.domain != "measurement":
                continue
            seg, ep = segs[jobs[k].segment], run.epochs[b]
            nominal = base.copy()
            nominal[ep] = seg.origin + fit.w_hat @ seg.rot
            rows = measurement_rows(data, nominal, cfg, False)
            free = 0.0
            for t, e in enumerate(ep):
                w = rows["w"][e] * run.mult[0, b, t] / factors[0]
                use = w > 0
                a = np.hstack([rows["P"][e][use], rows["C"][e][use]])
                a = a[:, np.any(a != 0, axis=0)]
                sw = np.sqrt(w[use])
                x = np.linalg.lstsq(a * sw[:, None], rows["y"][e][use] * sw, rcond=None)[0]
                free += float(np.sum(w[use] * (rows["y"][e][use] - a @ x) ** 2))
            assert fit.test_dof == 3 * ep.size - 3 * 3 - 2
            assert fit.test_stat == pytest.approx(fit.misfit - free, rel=1e-6, abs=1e-6)
            checked += 1
    assert checked >= 10


def test_statistic_is_chi_square_where_the_behavior_holds(noisy_arc: Path) -> None:
    """On a track the model class holds, with 1 m noise, the statistic per degree of freedom
    averages 1 (the variance factors put it in units of the file's own noise) and the test rejects
    no window at the default false-alarm probability: every epoch comes from a full-length window."""
    cfg, data, wls, ref = _load(noisy_arc, "pseudorange", **{"stls.window": 15})  # many windows' statistics
    sol, models = solve_multi_epoch("stls", data, wls, cfg)
    tested = [m for m in models if m.test_stat is not None]
    assert len(tested) >= 20
    ratio = np.array([m.test_stat / m.test_dof for m in tested])
    assert 0.8 <= ratio.mean() <= 1.25, ratio.mean()
    assert all(m.status != "rejected" for m in models)
    assert {m.n_epochs for m in models} == {cfg.stls.window}
    assert (sol.status == "ok").all()


@pytest.mark.parametrize("measurements", ["pseudorange", "pseudorange,doppler"])
def test_noise_free_manoeuvring_flight_is_reproduced_to_1_cm(exact_flight: Path, measurements: str) -> None:
    """Noise-free, the windows whose behavior the manoeuvres break are rejected and their epochs
    solved in shorter spans (or kept at the exact WLS fix): stls --lag 3 is the truth to 1 cm, where
    the same run without the test (``behavior_pfa = 0``: one untested whole segment) is off by
    decimetres to metres. ``integrity = "off"`` leaves the test on (it chooses the spans): without
    the gates it still rejects windows and reproduces the truth to 1 cm."""
    cfg, data, wls, ref = _load(exact_flight, measurements)
    sol, models = solve_multi_epoch("stls", data, wls, cfg)
    err = np.linalg.norm(sol.x_ecef_m - ref, axis=1)
    assert np.isfinite(err).all() and err.max() <= 0.01, err.max()
    rejected = [m for m in models if m.status == "rejected"]
    assert rejected and all(m.test_stat > m.test_limit for m in rejected)
    assert all(m.test_stat <= m.test_limit for m in models if m.test_stat is not None and m.status != "rejected")
    assert (sol.status == "ok").sum() > 0.5 * sol.status.size  # most epochs still come from a behavior
    t, answered = data.time_gps_s, np.zeros(data.time_gps_s.size, dtype=int)
    for m in models:  # the records' supplied spans: every epoch answered for by one record, once
        if m.n_supplied:
            mine = (t >= m.supplied_start_time_gps_s) & (t <= m.supplied_end_time_gps_s)
            assert mine.sum() == m.n_supplied and m.start_time_gps_s <= t[mine][0] <= t[mine][-1] <= m.end_time_gps_s
            answered += mine
        else:
            assert m.status == "rejected" and "solved again" in m.message and m.supplied_start_time_gps_s is None
    np.testing.assert_array_equal(answered, 1)
    untested, _ = solve_multi_epoch("stls", data, wls, replace(cfg, stls=replace(cfg.stls, behavior_pfa=0.0)))
    assert np.nanmax(np.linalg.norm(untested.x_ecef_m - ref, axis=1)) > 0.1
    ungated, ungated_models = solve_multi_epoch("stls", data, wls, replace(cfg, integrity="off"))
    assert np.nanmax(np.linalg.norm(ungated.x_ecef_m - ref, axis=1)) <= 0.01
    assert any(m.status == "rejected" for m in ungated_models)


@pytest.mark.parametrize("cross_faded", [False, True])
@pytest.mark.parametrize("lo, hi, length, n_seg", [(0, 8, 8, 100), (30, 38, 8, 100), (92, 100, 8, 100),
                                                   (10, 25, 10, 40), (0, 40, 20, 40), (5, 6, 8, 12)])
def test_shorter_windows_take_exactly_the_rejected_windows_epochs(lo: int, hi: int, length: int, n_seg: int,
                                                                  cross_faded: bool) -> None:
    """The windows of :func:`split_window` lie in the segment, have the new length, start half a
    window apart (a quarter where they are cross-faded; the last one may be closer, aligned with
    the end) and together supply each epoch the rejected window
    supplied, once."""
    job = WindowJob(segment=2, window=7, a=max(0, lo - 4), b=min(n_seg, hi + 4), lo=lo, hi=hi)
    out = split_window(job, length, n_seg, cross_faded)
    supplied = np.concatenate([np.arange(j.lo, j.hi) for j in out])
    np.testing.assert_array_equal(supplied, np.arange(lo, hi))
    for j in out:
        assert j.segment == 2 and 0 <= j.a <= j.lo < j.hi <= j.b <= n_seg and j.b - j.a == min(length, n_seg)
    steps = np.diff([j.a for j in out])
    step = max(1, length // (4 if cross_faded else 2))
    assert (steps[:-1] == step).all() and (0 < steps[-1:]).all() and (steps[-1:] <= step).all()


def test_limit_is_the_chi_square_quantile() -> None:
    from scipy.stats import chi2

    assert behavior_limit(13, 1e-3) == pytest.approx(chi2.ppf(1 - 1e-3, 13), rel=1e-9)
    assert behavior_limit(34, 1e-9) > behavior_limit(34, 1e-3)


def test_an_untested_window_covers_no_more_than_the_window_length(tmp_path: Path) -> None:
    """Whole segments (``--window 0``) halve on the behavior test; a window whose result stayed in
    the position domain has no test, and is split too while longer than the shortest window. On a
    simulated drive with range rates, an untested 150-epoch window was kept 62 m off (3D RMS 16 m,
    WLS 3.6 m); now every untested window that supplies epochs is short, and stls is within WLS's
    error."""
    d = _simulate(tmp_path / "drive", "drive", "noise", 1101, 300.0)
    cfg, data, wls, truth = _load(d, "pseudorange,doppler", **{"stls.window": 0})
    sol, models = solve_multi_epoch("stls", data, wls, cfg)
    untested = [m for m in models if m.status != "rejected" and m.test_stat is None]
    assert untested and max(m.n_epochs for m in untested) <= cfg.stls.min_window()
    assert any("not tested" in m.message for m in models)
    assert _rms3(sol.x_ecef_m, truth) < _rms3(wls.x_ecef_m, truth)


def _rms3(x: np.ndarray, ref: np.ndarray) -> float:
    e = np.linalg.norm(x - ref, axis=1)
    return float(np.sqrt(np.nanmean(e**2)))


def test_a_window_two_rejected_neighbours_share_is_solved_once(exact_flight: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """Two rejected neighbours split into the same shorter window (each copy supplying other epochs):
    the window is solved once, and the result is the one of solving every copy on its own. (In
    whole segments: their halves and quarters split on the flight into such windows.)"""
    cfg, data, wls, _ = _load(exact_flight, "pseudorange", **{"stls.window": 0})
    solved_windows: list[list[tuple[int, int, int]]] = []
    real = spans.alternate_windows

    def recording(data, wls, config, segs, jobs, *rest):  # type: ignore[no-untyped-def]
        solved_windows.append([(j.segment, j.a, j.b) for j in jobs])
        return real(data, wls, config, segs, jobs, *rest)

    monkeypatch.setattr(spans, "alternate_windows", recording)
    sol, models = solve_multi_epoch("stls", data, wls, cfg)
    assert all(len(set(w)) == len(w) for w in solved_windows)
    supplied = Counter((m.start_time_gps_s, m.end_time_gps_s) for m in models if m.n_supplied)
    assert max(supplied.values()) == 2  # the flight has such windows

    solved_windows.clear()
    monkeypatch.setattr(spans, "distinct_windows", lambda jobs: (list(range(len(jobs))), np.arange(len(jobs))))
    each, each_models = solve_multi_epoch("stls", data, wls, cfg)
    assert any(len(set(w)) < len(w) for w in solved_windows)
    # equal to rounding: the windows are solved in batches of another size (under numpy 1.x that
    # moved 7 of 543 coordinates by 1e-9 m and, by ending an alternation an iteration apart, a
    # window's misfit by 2e-6 relative)
    np.testing.assert_allclose(sol.x_ecef_m, each.x_ecef_m, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(sol.status, each.status)
    assert [(m.start_time_gps_s, m.end_time_gps_s, m.status, m.n_supplied, m.supplied_start_time_gps_s)
            for m in models] == [(m.start_time_gps_s, m.end_time_gps_s, m.status, m.n_supplied,
                                  m.supplied_start_time_gps_s) for m in each_models]
    for m, e in zip(models, each_models):
        assert (m.misfit is None) == (e.misfit is None) and (m.test_stat is None) == (e.test_stat is None)
        if m.misfit is not None:
            assert m.misfit == pytest.approx(e.misfit, rel=1e-4, abs=1e-9)
        if m.test_stat is not None:
            assert m.test_stat == pytest.approx(e.test_stat, rel=1e-4, abs=1e-6)


def test_whole_segments_keep_one_span_where_the_behavior_holds(noisy_arc: Path) -> None:
    """The default whole segments (``--window 0``) on a track the model class holds: the segment
    passes its test as one span, every epoch is solved in it, and averaging the whole segment
    beats the 15-epoch windows' estimate of the same track."""
    cfg, data, wls, ref = _load(noisy_arc, "pseudorange")
    assert cfg.stls.window == 0
    sol, models = solve_multi_epoch("stls", data, wls, cfg)
    assert len(models) == 1 and models[0].n_epochs == data.time_gps_s.size
    assert models[0].status != "rejected" and models[0].test_stat <= models[0].test_limit
    assert (sol.status == "ok").all()
    cfg15, *_ = _load(noisy_arc, "pseudorange", **{"stls.window": 15})
    windows15, _ = solve_multi_epoch("stls", data, wls, cfg15)
    rms = [float(np.sqrt(np.mean(np.sum((s.x_ecef_m - ref) ** 2, axis=1)))) for s in (sol, windows15)]
    assert rms[0] < rms[1], rms


def _pair_rows(py: np.ndarray, P3: np.ndarray, sigma_m: float) -> dict[str, np.ndarray]:
    """One window of two epochs: the pair rows ``py`` of the second epoch (the first has no pair)."""
    n = py.size
    rows = {"P6": np.zeros((1, 2, n, 6)), "pw": np.zeros((1, 2, n)), "py": np.zeros((1, 2, n)),
            "pC": np.ones((1, 2, n, 1))}
    rows["P6"][0, 1] = np.hstack([-P3, P3])
    rows["pw"][0, 1] = 1.0 / sigma_m**2
    rows["py"][0, 1] = py
    return rows


def test_the_behavior_test_counts_pair_rows_that_only_the_behavior_could_not_fit() -> None:
    """The gate leaves out every pair row above it. Where the rows agree on a displacement the
    behavior missed (5 cm), they come back into the test; a one-cycle slip (0.19 m) does not, among
    kept rows or among rows all left out; the pseudorange and range-rate multipliers are the gate's."""
    from types import SimpleNamespace

    from gnss_cli.pipeline.identified import _test_mult

    rng = np.random.default_rng(3)
    n, sigma = 8, 0.005
    P3 = rng.normal(size=(n, 3))
    P3 /= np.linalg.norm(P3, axis=1, keepdims=True)
    py = P3 @ np.array([0.03, -0.04, 0.0]) + 0.7 + rng.normal(0.0, 0.3 * sigma, n)  # displacement 5 cm, clock change
    gate = 3.29
    mult = rng.uniform(0.5, 1.0, size=(3, 1, 2, n))
    factors = (1.0, 1.0, 1.0)

    every = np.zeros((3, 1, 2, n), dtype=bool)
    every[2, 0, 1] = True  # the behavior at zero displacement: every pair row out
    run = SimpleNamespace(mult=np.where(every, 0.0, mult), gated=every)
    out = _test_mult(run, _pair_rows(py, P3, sigma), factors, gate)
    assert (out[2, 0, 1] == 1.0).all()
    np.testing.assert_array_equal(out[:2], run.mult[:2])

    slipped = py.copy()
    slipped[4] += 0.19
    for gated_rows in ([4], list(range(n))):  # the slip alone out; every row out
        g = np.zeros((3, 1, 2, n), dtype=bool)
        g[2, 0, 1, gated_rows] = True
        run = SimpleNamespace(mult=np.where(g, 0.0, mult), gated=g)
        out = _test_mult(run, _pair_rows(slipped, P3, sigma), factors, gate)
        assert out[2, 0, 1, 4] == 0.0, gated_rows
        if len(gated_rows) == 1:
            np.testing.assert_array_equal(out, run.mult)


def test_a_window_rejected_at_the_shortest_length_drops_its_most_precise_measurements_first(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Rejected at the shortest length, a window with phase is solved again without the phase
    (pseudoranges and range rates), and only one rejected with those with the pseudoranges alone:
    where a behavior cannot follow the antenna to the millimetres of the phase differences, the
    range rates may still hold it. (A simulated drive with phase, ``behavior_pfa`` 0.5 so that the
    test rejects at every length.)"""
    from gnss_cli.pipeline.spans import fewer_measurements

    base = ScenarioConfig()
    d = tmp_path / "drive"
    write_scenario(run_scenario(replace(base, trajectory="drive", duration_s=120.0, interval_s=1.0, seed=1101,
                                        errors=base.errors.with_sources(parse_error_list("noise")),
                                        layout=replace(base.layout, phase=True))), d)
    cfg, data, wls, _ = _load(d, "pseudorange,doppler,phase", **{"stls.window": 0, "stls.behavior_pfa": 0.5})
    stages: list[frozenset[str]] = []
    real = spans.alternate_windows

    def recording(data, wls, config, segs, jobs, fits, kinds, *rest):  # type: ignore[no-untyped-def]
        stages.append(kinds)
        return real(data, wls, config, segs, jobs, fits, kinds, *rest)

    monkeypatch.setattr(spans, "alternate_windows", recording)
    _, models = solve_multi_epoch("stls", data, wls, cfg)
    every, without_phase, alone = (frozenset(k.split(",")) for k in
                                   ("pseudorange,doppler,phase", "pseudorange,doppler", "pseudorange"))
    assert fewer_measurements(every) == without_phase and fewer_measurements(without_phase) == alone
    first = {kinds: stages.index(kinds) for kinds in (every, without_phase, alone)}  # each kind set is solved
    assert first[every] == 0 and max(i for i, k in enumerate(stages) if k == every) < first[without_phase]
    assert max(i for i, k in enumerate(stages) if k == without_phase) < first[alone]
    shortest = cfg.stls.min_window()
    retried = {(m.message.split("measurement domain (")[1].split(")")[0], m.message.split(";")[1].split(" in windows")[0])
               for m in models if m.status == "rejected" and m.n_epochs == shortest
               and "measurement domain (" in m.message and "solved again with" in m.message}
    assert retried == {("pseudorange+doppler+phase", " its epochs solved again with pseudorange+doppler"),
                       ("pseudorange+doppler", " its epochs solved again with the pseudoranges alone")}
