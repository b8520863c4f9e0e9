"""Measurement-domain window solutions against dense least squares."""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.behavior.multi_epoch import shared_behavior_bases
from gnss_cli.behavior.window_solve import free_misfit, reduce_epochs, solve_windows, velocity_operator


def _epochs(rng: np.random.Generator, n_t: int, n: int, k: int, n_sats: list[int]) -> tuple[np.ndarray, ...]:
    """Random unit line-of-sight rows, weights (0 beyond each epoch's satellite count), values, clock columns."""
    e = rng.normal(size=(n_t, n, 3))
    e /= np.linalg.norm(e, axis=-1, keepdims=True)
    w = rng.uniform(0.5, 2.0, size=(n_t, n)) * (np.arange(n)[None, :] < np.array(n_sats)[:, None])
    y = rng.normal(size=(n_t, n))
    sys_of = np.arange(n) % k
    c = np.broadcast_to((sys_of[:, None] == np.arange(k)).astype(float), (n_t, n, k)).copy()
    return -e, w, y, c


def _dense_clock_misfit(p: np.ndarray, w: np.ndarray, y: np.ndarray, c: np.ndarray, z: np.ndarray) -> float:
    """min over the clocks of one epoch's weighted misfit at position correction z (dense lstsq)."""
    used = w > 0
    sw = np.sqrt(w[used])
    cols = c[used][:, c[used].any(axis=0)]
    resid = y[used] - p[used] @ z
    if cols.shape[1] == 0:
        return float(np.sum(w[used] * resid**2))
    b, *_ = np.linalg.lstsq(cols * sw[:, None], resid * sw, rcond=None)
    return float(np.sum(w[used] * (resid - cols @ b) ** 2))


def test_reduced_normals_give_the_clock_minimized_misfit() -> None:
    rng = np.random.default_rng(1)
    p, w, y, c = _epochs(rng, 5, 9, 2, [9, 6, 3, 2, 1])
    nrm = reduce_epochs(p, w, y, c)
    for t in range(5):
        z = rng.normal(size=3)
        quad = nrm.s[t] - 2 * z @ nrm.r[t] + z @ nrm.M[t] @ z
        assert quad == pytest.approx(_dense_clock_misfit(p[t], w[t], y[t], c[t], z), rel=1e-10, abs=1e-10)
    # one satellite: its clock takes the row, the position learns nothing
    assert np.allclose(nrm.M[4], 0.0) and nrm.s[4] == pytest.approx(0.0, abs=1e-12)
    assert nrm.n_rows.tolist() == [9, 6, 3, 2, 1] and nrm.n_free.tolist() == [2, 2, 2, 2, 1]


def test_free_misfit_is_each_epoch_solved_alone() -> None:
    rng = np.random.default_rng(2)
    p, w, y, c = _epochs(rng, 4, 8, 1, [8, 5, 4, 2])
    nrm = reduce_epochs(p, w, y, c)
    mis, rank = free_misfit(nrm)
    for t in range(4):
        used = w[t] > 0
        a = np.hstack([p[t][used], c[t][used]]) * np.sqrt(w[t][used])[:, None]
        sol, *_ = np.linalg.lstsq(a, y[t][used] * np.sqrt(w[t][used]), rcond=None)
        assert mis[t] == pytest.approx(float(np.sum((y[t][used] * np.sqrt(w[t][used]) - a @ sol) ** 2)), abs=1e-9)
    assert rank.tolist() == [3, 3, 3, 1]


def test_window_solution_equals_the_dense_stacked_multi_epoch_geometry() -> None:
    """theta from the clock-reduced normals equals lstsq on G_N = [blkdiag(P_t) O, blkdiag(C_t)]
    (and, with range rates, the velocity rows with one drift per epoch), epochs with 1-3
    satellites included."""
    rng = np.random.default_rng(3)
    n_t, n, k = 9, 7, 2
    p, w, y, c = _epochs(rng, n_t, n, k, [7, 3, 2, 1, 6, 7, 2, 5, 7])
    h, wd, yd, _ = _epochs(rng, n_t, n, 1, [7, 3, 2, 1, 6, 7, 2, 5, 7])
    basis = shared_behavior_bases(np.array([[-1.0, 3.0, -3.0, 1.0]]), n_t, 3)[0]
    vel = velocity_operator(basis, 1.0)
    offset = rng.normal(size=(n_t, 3))
    spans = np.arange(n_t)[None]
    sol = solve_windows(basis[None], spans, offset[None], reduce_epochs(p, w, y, c), vel[None], reduce_epochs(h, wd, yd))
    K = basis.shape[-1]
    rows, rhs = [], []
    n_clk = n_t * k + n_t
    for t in range(n_t):
        for i in np.flatnonzero(w[t] > 0):
            r = np.zeros(K + n_clk)
            r[:K] = p[t, i] @ basis[t]
            r[K + t * k : K + (t + 1) * k] = c[t, i]
            rows.append(r * np.sqrt(w[t, i]))
            rhs.append((y[t, i] - p[t, i] @ offset[t]) * np.sqrt(w[t, i]))
        for i in np.flatnonzero(wd[t] > 0):
            r = np.zeros(K + n_clk)
            r[:K] = h[t, i] @ vel[t]
            r[K + n_t * k + t] = 1.0
            rows.append(r * np.sqrt(wd[t, i]))
            rhs.append(yd[t, i] * np.sqrt(wd[t, i]))
    a, b = np.array(rows), np.array(rhs)
    dense, *_ = np.linalg.lstsq(a, b, rcond=None)
    assert sol.ok[0]
    assert np.allclose(sol.theta[0], dense[:K], rtol=1e-8, atol=1e-9)
    assert sol.misfit[0] == pytest.approx(float(np.sum((b - a @ dense) ** 2)), rel=1e-8)
    assert sol.dof[0] == a.shape[0] - np.linalg.matrix_rank(a)


def test_singular_window_is_reported_not_solved() -> None:
    rng = np.random.default_rng(4)
    p, w, y, c = _epochs(rng, 5, 4, 1, [1, 1, 1, 1, 1])  # one satellite each: no position information
    basis = shared_behavior_bases(np.array([[-1.0, 1.0]]), 5, 3)[0]
    sol = solve_windows(basis[None], np.arange(5)[None], np.zeros((1, 5, 3)), reduce_epochs(p, w, y, c))
    assert not sol.ok[0] and np.isnan(sol.theta).all()
