"""The spans of ``stls --lag 3`` solved together (:mod:`gnss_cli.pipeline.tied`): the result lies in
each span's identified behavior, the runs are those of the spans, tying them beats solving them
one at a time, and a latency relaxes the behavior."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gnss_cli.config import load_config
from gnss_cli.io.reference import reference_from_csv
from gnss_cli.pipeline import load_epochs, solve_method
from gnss_cli.pipeline.behavioral import Fit, WindowJob
from gnss_cli.pipeline.methods import method_settings, solve_multi_epoch
from gnss_cli.pipeline.tied import _free, span_runs
from gnss_cli.sim.error_sources import parse_error_list
from gnss_cli.sim.scenario import ScenarioConfig, run_scenario, write_scenario

BASE = {"methods": "wls,stls", "stls.lag": 3, "iono": "none", "tropo": "none", "stls.window": 0}


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A simulated drive (training seed 1001 of ``benchmarks/multi_epoch_fair.py``) with 1 m code noise."""
    out = tmp_path_factory.mktemp("drive")
    base = ScenarioConfig()
    cfg = replace(base, trajectory="drive", duration_s=300.0, interval_s=1.0, seed=1001, systems=("G",),
                  errors=replace(base.errors.with_sources(parse_error_list("noise")), noise_sigma_m=1.0))
    write_scenario(run_scenario(cfg), out)
    return out


def _load(d: Path, measurements: str):  # type: ignore[no-untyped-def]
    cfg = load_config(None, {**BASE, "measurements": measurements})
    data = load_epochs(d / "obs.rnx", [d / "nav.rnx"], cfg)
    return cfg, data, solve_method(data, "wls", cfg), np.asarray(reference_from_csv(d / "truth.csv", data.time_gps_s))


def _rms(x: np.ndarray, ref: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(np.sum((x - ref) ** 2, axis=1))))


def _untied(monkeypatch: pytest.MonkeyPatch) -> None:
    import gnss_cli.pipeline.tied as tied

    monkeypatch.setattr(tied, "tie_spans", lambda data, wls, config, segs, jobs, fits, *rest: (
        fits, np.zeros(data.usable.shape, dtype=bool), np.zeros(data.time_gps_s.size, dtype=bool),
        np.full((data.time_gps_s.size, 3), np.nan)))


def test_the_tied_track_lies_in_each_spans_behavior(drive: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every tied span of at least ``l + 1`` epochs: its kernel applied to the output positions
    (each coordinate, relative to the span's first epoch) vanishes at every shift inside the span,
    while across the switches it does not (the switch rows are soft); the windows' records say
    they were tied, with the switch rows' sigma."""
    import gnss_cli.pipeline.tied as tied

    seen: dict[str, object] = {}
    original = tied.tie_spans

    def spy(data, wls, config, segs, jobs, fits, *rest):  # type: ignore[no-untyped-def]
        out = original(data, wls, config, segs, jobs, fits, *rest)
        seen.update(segs=segs, jobs=jobs, runs=tied.span_runs(segs, jobs, fits))
        return out

    monkeypatch.setattr(tied, "tie_spans", spy)
    cfg, data, wls, _ = _load(drive, "pseudorange,doppler")
    sol, models = solve_multi_epoch("stls", data, wls, cfg)
    assert any("tied (velocities by the lag-2 quadrature; switch rows sigma" in m.message for m in models)
    segs, jobs, runs = seen["segs"], seen["jobs"], seen["runs"]
    inside, across = [], []
    for run in runs:  # type: ignore[attr-defined]
        for k, k_next in zip(run, [*run[1:], None]):
            job = jobs[k]  # type: ignore[index]
            epochs = segs[job.segment].epochs  # type: ignore[index]
            if "without its kernel rows" in models[k].message:
                continue  # a span in its run without a behavior (tests/behavior/test_piecewise.py)
            r = np.asarray(models[k].kernel.shared_coefficients)
            own = epochs[job.lo : job.hi]
            x = sol.x_ecef_m[own] - sol.x_ecef_m[own[0]]
            inside += [np.abs(r @ x[i : i + r.size]).max() for i in range(own.size - r.size + 1)]
            if k_next is not None and own.size >= r.size - 1:
                span = epochs[job.hi - r.size + 1 : job.hi + 1]
                across.append(np.abs(r @ (sol.x_ecef_m[span] - sol.x_ecef_m[span[0]])).max())
    assert len(inside) > 50 and max(inside) < 1e-6
    assert across and max(across) > 1e-3


def test_tying_beats_the_spans_solved_alone(drive: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With range rates, the same spans and kernels solved together rather than one at a time are
    closer to the truth (measured on this drive, 3D RMS: 0.38 m tied, 1.24 m alone, with
    ``behavior_pfa`` 1e-12); with the pseudoranges alone the spans are not tied."""
    cfg, data, wls, truth = _load(drive, "pseudorange,doppler")
    cfg = replace(cfg, stls=replace(cfg.stls, behavior_pfa=1e-12))
    sol, _ = solve_multi_epoch("stls", data, wls, cfg)
    with monkeypatch.context() as mp:
        _untied(mp)
        alone, _ = solve_multi_epoch("stls", data, wls, cfg)
    assert _rms(sol.x_ecef_m, truth) < 0.95 * _rms(alone.x_ecef_m, truth), (_rms(sol.x_ecef_m, truth),
                                                                           _rms(alone.x_ecef_m, truth))
    cfg, data, wls, _ = _load(drive, "pseudorange")
    _, models = solve_multi_epoch("stls", data, wls, cfg)
    assert models and not any("tied" in m.message for m in models)


def test_a_latency_relaxes_the_behavior_and_never_raises_the_runs_cost(drive: Path) -> None:
    """``stls.latency_m`` makes the kernel rows soft: under the same residual gate the run's cost
    (weighted measurement misfit plus the soft rows) cannot exceed the exact behavior's, whose
    trajectory is a candidate of the relaxed problem at no kernel cost, and it falls as the latency
    grows (the gate, evaluated at each solution, may keep a row more: a cost over more rows is not
    compared); a tiny latency gives the exact behavior's track; the records and the model say what ran."""
    cfg, data, wls, _ = _load(drive, "pseudorange,doppler")
    costs, dofs, tracks = [], [], []
    for latency in (0.0, 1e-4, 0.01, 0.1, 1.0):
        one = replace(cfg, stls=replace(cfg.stls, latency_m=latency))
        sol, models = solve_multi_epoch("stls", data, wls, one)
        runs = {m.message.rsplit("run misfit ", 1)[1] for m in models if "run misfit" in m.message}
        costs.append(sum(float(r.split()[0]) for r in runs))
        dofs.append(sum(int(r.split()[2]) for r in runs))
        tracks.append(sol.x_ecef_m)
        assert (f"latency {latency:.3g} m;" in models[0].message) == (latency > 0) or "run misfit" not in models[0].message
        model = method_settings(one, True, False)["stls"].model
        assert model.endswith("spans tied (velocities by the lag-2 quadrature)"
                              + (f", latency {latency:g} m" if latency else "")), model
    same_gate = [(a, b) for a, b, m, n in zip(costs, costs[1:], dofs, dofs[1:]) if m == n]
    assert len(same_gate) >= 2 and all(b <= a * (1 + 1e-6) for a, b in same_gate), (costs, dofs)
    assert costs[-1] < 0.99 * costs[0], costs
    assert np.nanmax(np.abs(tracks[1] - tracks[0])) < 1e-3
    assert np.nanmax(np.abs(tracks[-1] - tracks[0])) > 1e-2


def test_runs_are_maximal_sequences_of_spans_with_a_trajectory() -> None:
    """A span that keeps the WLS fix, or a gap, ends a run; a span whose result stayed in the
    position domain joins its run without a behavior (no kernel rows, no switch row out of it)."""
    from gnss_cli.pipeline.behavioral import Segment

    seg = Segment(np.arange(40), np.zeros(3), np.eye(3), np.zeros((40, 3)), np.zeros((40, 3, 3)))
    kernel = type("K", (), {"shared_coefficients": (-1.0, 3.0, -3.0, 1.0)})()

    def fit(domain: str = "measurement", w: bool = True) -> Fit:
        return Fit(np.zeros((10, 3)) if w else None, kernel, 0.0, None, "", None, domain=domain)  # type: ignore[arg-type]

    jobs = [WindowJob(0, i, lo, lo + 10, lo, lo + 5) for i, lo in enumerate(range(0, 40, 5))]
    fits = [fit(), fit(), fit(w=False), fit(), fit(domain="position"), fit(), fit(), fit()]
    jobs[6] = replace(jobs[6], lo=31, hi=35)  # a gap before it (epoch 30 supplied by no span)
    assert span_runs([seg], jobs, fits) == [[0, 1], [3, 4, 5], [6, 7]]
    kinds = frozenset({"pseudorange", "doppler"})
    assert [_free(f, kinds) for f in fits[3:6]] == [False, True, False]
    assert _free(replace(fits[3], measurements=frozenset({"pseudorange"})), kinds)


@pytest.mark.parametrize("measurements", ["pseudorange,doppler", "pseudorange"])
def test_a_run_bridges_missed_epochs(drive: Path, measurements: str) -> None:
    """The drive without its epochs 1 and 150-152 (the Yamatogawa walk's first step is two seconds):
    with range rates the run takes in epoch 0, a segment too short for a window, and joins the
    spans on either side of the 4 s step -- every epoch ``ok``, the records say so, and the track is
    as good as with every epoch (3D RMS within 10 % over the epochs both have; measured 0.351
    against 0.357 m, epoch 0 0.63 m off where its WLS fix is 2.2 m off); with the pseudoranges alone
    nothing ties the spans, and epoch 0 keeps its WLS fix (``fallback_wls``)."""
    from gnss_cli.pipeline.integrity import take_epochs

    cfg, full, full_wls, ref = _load(drive, measurements)
    rows = np.r_[0, 2:150, 153:full.time_gps_s.size]
    data = take_epochs(full, rows)
    wls = solve_method(data, "wls", cfg)
    sol, models = solve_multi_epoch("stls", data, wls, cfg)
    if measurements == "pseudorange":
        assert sol.status[0] == "fallback_wls"
        np.testing.assert_array_equal(sol.x_ecef_m[0], wls.x_ecef_m[0])
        return
    assert (sol.status == "ok").all()
    said = [m.message for m in models if "across" in m.message]
    assert said and all("across 2 gaps of missed epochs with 1 epoch of segments too short for a window" in m
                        for m in said)
    every, _ = solve_multi_epoch("stls", full, full_wls, cfg)
    assert _rms(sol.x_ecef_m, ref[rows]) < 1.1 * _rms(every.x_ecef_m[rows], ref[rows])
    assert np.linalg.norm(sol.x_ecef_m[0] - ref[0]) < np.linalg.norm(wls.x_ecef_m[0] - ref[0])


def test_a_run_bridges_an_epoch_without_a_fix_but_not_a_span_that_kept_its_wls_fixes() -> None:
    """With range rates, an epoch WLS could not fix (too few satellites; in no segment) is bridged
    as a missed one is: the spans on either side are one run, the quadrature rule over the 2 s step
    (a simulated single-profile canyon drive: its first 29 epochs, cut off by such an epoch, were
    25 m off in a run of their own, 3D RMS 5.71 m; bridged 1.74 m, ``smoother`` 2.19 m). An epoch
    with a fix that no span supplies (its span kept the WLS fixes) still ends a run, as without
    range rates the step does."""
    from gnss_cli.pipeline.behavioral import Segment
    from gnss_cli.pipeline.tied import bridged_runs

    def seg(epochs: np.ndarray) -> Segment:
        n = epochs.size
        return Segment(epochs, np.zeros(3), np.eye(3), np.zeros((n, 3)), np.zeros((n, 3, 3)))

    kernel = type("K", (), {"shared_coefficients": (-1.0, 3.0, -3.0, 1.0)})()

    def fit(w: bool = True) -> Fit:
        return Fit(np.zeros((10, 3)) if w else None, kernel, 0.0, None, "", None, domain="measurement")  # type: ignore[arg-type]

    t, none = np.arange(40.0), np.zeros(0, dtype=np.intp)
    segs = [seg(np.arange(20)), seg(np.arange(21, 40))]  # epoch 20: no fix
    jobs = [WindowJob(0, 0, 0, 10, 0, 10), WindowJob(0, 1, 10, 20, 10, 20),
            WindowJob(1, 0, 0, 10, 0, 10), WindowJob(1, 1, 9, 19, 10, 19)]
    fits = [fit() for _ in jobs]
    runs = bridged_runs(t, segs, jobs, fits, none, True)
    assert len(runs) == 1
    np.testing.assert_array_equal(np.concatenate([e for _, e in runs[0]]), np.r_[0:20, 21:40])
    assert len(bridged_runs(t, segs, jobs, fits, none, False)) == 2

    whole = [seg(np.arange(40))]  # epoch 20 fixed, its span keeping the WLS fix
    jobs = [WindowJob(0, 0, 0, 10, 0, 10), WindowJob(0, 1, 10, 20, 10, 20), WindowJob(0, 2, 15, 25, 20, 21),
            WindowJob(0, 3, 21, 31, 21, 31), WindowJob(0, 4, 30, 40, 31, 40)]
    fits = [fit(), fit(), fit(w=False), fit(), fit()]
    assert len(bridged_runs(t, whole, jobs, fits, none, True)) == 2


def test_a_bridged_epoch_without_a_fix_leaves_out_the_pair_that_differences_against_it() -> None:
    """A phase pair differences an epoch with the one before it in the data: in a run that skips
    epoch 6 (no fix), the pair ending at 7 (6 -> 7) is not a displacement between the run's
    neighbours 5 and 7, so it is left out, as the pair ending at the run's first epoch is."""
    from gnss_cli.behavior.window_solve import EpochNormals
    from gnss_cli.pipeline.smoother import _segment_pairs

    T = 10
    rng = np.random.default_rng(0)
    ph = EpochNormals(rng.normal(size=(T, 6, 6)), rng.normal(size=(T, 6)), rng.normal(size=T),
                      np.full(T, 5, dtype=np.int64), np.ones(T, dtype=np.int64))
    seg = np.array([3, 4, 5, 7, 8])
    sub = _segment_pairs(ph, seg)
    kept = np.array([False, True, True, False, True])
    np.testing.assert_array_equal(sub.n_rows, np.where(kept, 5, 0))
    np.testing.assert_array_equal(sub.M[kept], ph.M[seg[kept]])
    assert not sub.M[~kept].any() and not sub.r[~kept].any() and not sub.s[~kept].any()
