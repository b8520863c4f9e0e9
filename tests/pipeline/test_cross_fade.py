"""Overlapping windows of ``stls --lag L`` cross-faded where their spans are not tied (pseudoranges
alone, or the position domain): the weights, the positions as the weighted mean of the windows'
estimates (checked against a direct computation), the covariance bound, and the tied path unchanged."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gnss_cli.behavior.multi_epoch import epoch_information, window_covs
from gnss_cli.pipeline import behavioral
from gnss_cli.pipeline.behavioral import DopWindow, WindowJob, blended, window_weights
from gnss_cli.pipeline.methods import method_settings, solve_multi_epoch
from test_spans import _load, _simulate


@pytest.fixture(scope="module")
def noisy_flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A manoeuvring flight with 1 m code noise, 300 s: in whole segments the behavior test splits
    it into overlapping windows, one of them taken by two rejected neighbours."""
    return _simulate(tmp_path_factory.mktemp("flight"), "flight", "noise", 4, 300.0)


def test_weights_are_triangular_or_the_supplied_epochs() -> None:
    job = WindowJob(segment=0, window=1, a=10, b=17, lo=12, hi=15)
    np.testing.assert_array_equal(window_weights(job, True), [1, 2, 3, 4, 3, 2, 1])
    np.testing.assert_array_equal(window_weights(job, False), [0, 0, 1, 1, 1, 0, 0])
    even = WindowJob(0, 0, 0, 6, 0, 3)
    np.testing.assert_array_equal(window_weights(even, True), [1, 2, 3, 3, 2, 1])


def test_blend_is_the_weighted_mean_of_the_windows_covering_an_epoch() -> None:
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(6, 3)), rng.normal(size=(6, 3))
    wa, wb = np.arange(1.0, 7.0), np.array([2.0, 1.0, 0.0, 5.0, 1.0, 1.0])
    out = blended(12, [(np.arange(0, 6), a, wa), (np.arange(3, 9), b, wb)])
    np.testing.assert_allclose(out[:3], a[:3], rtol=0, atol=1e-15)  # one window: its own estimate
    for t in range(3, 6):
        expect = (wa[t] * a[t] + wb[t - 3] * b[t - 3]) / (wa[t] + wb[t - 3])
        np.testing.assert_allclose(out[t], expect, rtol=1e-14)
    np.testing.assert_allclose(out[6:9], b[3:], rtol=1e-14)
    assert np.isnan(out[9:]).all()  # no window: no estimate


def test_mean_of_covariances_bounds_the_covariance_of_the_mean() -> None:
    """The bound :func:`~gnss_cli.pipeline.behavioral._window_gains` reports: for convex weights and
    any correlation of the estimates, ``cov(sum a_i x_i) <= sum a_i cov(x_i)`` (Loewner order)."""
    rng = np.random.default_rng(11)
    for _ in range(200):
        m = rng.normal(size=(9, 9)) @ np.diag(rng.uniform(0.01, 3.0, 9)) @ rng.normal(size=(9, 9))
        joint = m @ m.T  # three 3-vector estimates, correlated at random
        a = rng.dirichlet(np.ones(3))
        mix = np.kron(a[None, :], np.eye(3))
        bound = sum(a[i] * joint[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] for i in range(3))
        assert np.linalg.eigvalsh(bound - mix @ joint @ mix.T).min() >= -1e-9 * np.trace(bound)


def test_window_gains_are_the_weighted_mean_of_each_windows() -> None:
    """Two overlapping windows with a constant-velocity basis on random geometry: each epoch's
    covariance is the weighted mean of the windows' own (``window_covs`` one window at a time), an
    epoch of a window without a basis keeps the covariance it had."""
    rng = np.random.default_rng(5)
    T, n = 14, 7
    p = rng.normal(size=(T, n, 3))
    p /= np.linalg.norm(p, axis=2, keepdims=True)
    geometry = {"w": epoch_information(p, rng.uniform(0.5, 2.0, (T, n))),
                "u": epoch_information(p, np.ones((T, n)))}
    t = np.arange(8.0)
    basis = np.zeros((8, 3, 6))
    basis[:, :, :3] = np.eye(3)
    basis[:, :, 3:] = t[:, None, None] * np.eye(3)
    w1, w2 = np.minimum(np.arange(8) + 1, 8 - np.arange(8)).astype(float), np.ones(8)
    wins = [DopWindow(np.arange(0, 8), basis, w1), DopWindow(np.arange(4, 12), basis, w2),
            DopWindow(np.arange(12, 14), None, np.ones(2))]
    cov = np.tile(np.eye(4) * 99.0, (T, 1, 1))
    smoothed = np.ones(T, dtype=bool)
    smoothed[11] = False
    gain = behavioral._window_gains(T, 1, wins, geometry, cov, smoothed)
    c1 = window_covs(basis[None], np.arange(0, 8)[None], *geometry["w"])[0]
    c2 = window_covs(basis[None], np.arange(4, 12)[None], *geometry["w"])[0]
    u1 = window_covs(basis[None], np.arange(0, 8)[None], *geometry["u"])[0]
    np.testing.assert_allclose(cov[:4], c1[:4], rtol=1e-12)
    np.testing.assert_allclose(gain[:4], u1[:4], rtol=1e-12)
    for k in range(4, 8):
        expect = (w1[k] * c1[k] + c2[k - 4]) / (w1[k] + 1.0)
        np.testing.assert_allclose(cov[k], expect, rtol=1e-12)
    np.testing.assert_allclose(cov[8:11], c2[4:7], rtol=1e-12)
    np.testing.assert_array_equal(cov[11:], np.tile(np.eye(4) * 99.0, (3, 1, 1)))  # not smoothed; no basis
    assert np.isnan(gain[11:]).all()


def test_flight_positions_are_the_cross_fade_of_the_windows(noisy_flight: Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """With pseudoranges alone every smoothed epoch is the triangular-weighted mean of the accepted
    windows over it, each distinct window counted once (computed here from the windows' own
    estimates), and the reported model says so. Without the cross-fade each epoch is the estimate
    of the window that supplies it, as where spans are tied."""
    cfg, data, wls, _ = _load(noisy_flight, "pseudorange", **{"stls.window": 0})
    seen: list[list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = []
    real = behavioral.blended

    def recording(T, estimates):  # type: ignore[no-untyped-def]
        seen.append(list(estimates))
        return real(T, estimates)

    monkeypatch.setattr(behavioral, "blended", recording)
    sol, _ = solve_multi_epoch("stls", data, wls, cfg)
    T = data.time_gps_s.size
    total, weight, covering = np.zeros((T, 3)), np.zeros(T), np.zeros(T, dtype=int)
    windows: dict[tuple[int, int], np.ndarray] = {}
    copies = 0
    for span, x, w in seen[0]:
        key = (int(span[0]), int(span[-1]))
        if key in windows:  # a copy of a window already counted has no weight
            assert not w.any()
            copies += 1
        windows[key] = x
    assert copies >= 1
    for (first, last), x in windows.items():
        for i, t in enumerate(range(first, last + 1)):
            tri = min(i + 1, last - first + 1 - i)
            total[t] += tri * x[i]
            weight[t] += tri
            covering[t] += 1
    ok = sol.status == "ok"
    assert ok.mean() > 0.9 and (weight[ok] > 0).all()
    np.testing.assert_allclose(sol.x_ecef_m[ok], total[ok] / weight[ok, None], rtol=0, atol=1e-6)
    assert (covering[ok] >= 2).mean() > 0.3  # epochs shared by two windows or more
    assert "overlapping windows cross-faded" in method_settings(cfg, True, True)["stls"].model

    monkeypatch.setattr(behavioral, "window_weights", lambda job, cross_fade: window_weights(job, False))
    seen.clear()
    alone, _ = solve_multi_epoch("stls", data, wls, cfg)
    owner = {int(t): x[i] for span, x, w in seen[0] for i, t in enumerate(span) if w[i] > 0}
    ok = alone.status == "ok"
    np.testing.assert_array_equal(alone.x_ecef_m[ok], np.array([owner[int(t)] for t in np.flatnonzero(ok)]))
    assert np.abs(alone.x_ecef_m[ok] - sol.x_ecef_m[ok]).max() > 0.01


def test_tied_spans_are_not_cross_faded(noisy_flight: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With range rates the spans are tied into one trajectory: each epoch is its span's estimate
    alone, exactly as before cross-fading existed (the weights are the supplied epochs)."""
    cfg, data, wls, _ = _load(noisy_flight, "pseudorange,doppler", **{"stls.window": 0})
    calls: list[bool] = []

    def spy(job, cross_fade):  # type: ignore[no-untyped-def]
        calls.append(cross_fade)
        return window_weights(job, cross_fade)

    monkeypatch.setattr(behavioral, "window_weights", spy)
    sol, _ = solve_multi_epoch("stls", data, wls, replace(cfg))
    assert calls and not any(calls)
    assert (sol.status == "ok").mean() > 0.9
