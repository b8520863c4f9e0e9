"""Clock-reduced epoch normals and the kinematic segment solve against dense least squares."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import null_space

from gnss_cli.behavior import kinematic_solve
from gnss_cli.behavior.kinematic_solve import JERK_SIGMA_M_S3, solve_kinematic, step_rule
from gnss_cli.behavior.window_solve import free_misfit, reduce_epochs


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


def _kinematic_dense(pr, rr, step_m, dt_s, lag):  # type: ignore[no-untyped-def]
    """The same constrained problem through the null space of the constraints (dense)."""
    n = pr.M.shape[0]
    G = np.zeros((3 * (n - 1), 6 * n))
    cvec = -step_m.ravel()
    for t in range(n - 1):
        offs, wts = step_rule(t, n, lag)
        for a in range(3):
            G[3 * t + a, 3 * (t + 1) + a] += 1.0
            G[3 * t + a, 3 * t + a] -= 1.0
            for o, wt in zip(offs, wts):
                G[3 * t + a, 3 * n + 3 * (t + o) + a] -= wt * dt_s[t]
    H = np.zeros((6 * n, 6 * n))
    for t in range(n):
        H[3 * t : 3 * t + 3, 3 * t : 3 * t + 3] = pr.M[t]
        H[3 * n + 3 * t : 3 * n + 3 * t + 3, 3 * n + 3 * t : 3 * n + 3 * t + 3] = rr.M[t]
    d2 = np.diff(np.eye(n), 2, axis=0)  # v_{t+1} - 2 v_t + v_{t-1} (uniform steps here)
    H[3 * n :, 3 * n :] += np.kron(d2.T @ d2 / (JERK_SIGMA_M_S3 * dt_s[0] ** 2) ** 2, np.eye(3))
    g = np.concatenate([pr.r.ravel(), rr.r.ravel()])
    u0, *_ = np.linalg.lstsq(G, cvec, rcond=None)
    N = null_space(G)
    a = np.linalg.solve(N.T @ H @ N, N.T @ (g - H @ u0))
    u = u0 + N @ a
    return u[: 3 * n].reshape(n, 3), u[3 * n :].reshape(n, 3)


@pytest.mark.parametrize("lag", [1, 2, 3])
def test_kinematic_segment_equals_the_null_space_solution(lag: int) -> None:
    rng = np.random.default_rng(10 + lag)
    n_t = 12
    p, w, y, c = _epochs(rng, n_t, 8, 1, [8] * n_t)
    h, wd, yd, _ = _epochs(rng, n_t, 8, 1, [8] * n_t)
    pr, rr = reduce_epochs(p, w, y, c), reduce_epochs(h, wd, yd)
    step = rng.normal(size=(n_t - 1, 3))
    dt = np.full(n_t - 1, 0.5)
    sol = solve_kinematic(pr, rr, step, dt, lag)
    z, v = _kinematic_dense(pr, rr, step, dt, lag)
    assert np.allclose(sol.z, z, rtol=1e-8, atol=1e-9) and np.allclose(sol.v, v, rtol=1e-8, atol=1e-9)
    assert sol.dof == 2 * 8 * n_t - 2 * n_t - 3 * n_t - 3


@pytest.mark.parametrize("lag, exact", [(1, False), (3, True)])
def test_kinematic_rule_of_lag_3_is_exact_for_cubic_velocity(lag: int, exact: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """Noise-free rows of a trajectory with a polynomial velocity: the lag-3 rule (one-sided at the ends) returns it, the
    trapezoid does not (its step error is dt^3 x''' / 12)."""
    monkeypatch.setattr(kinematic_solve, "JERK_SIGMA_M_S3", 1e6)  # the prior (3 m/s^3) pulls 1e-4 m here
    rng = np.random.default_rng(5)
    n_t, dt = 40, 1.0
    t = np.arange(n_t) * dt
    coef = np.array([[0.3, -0.2, 0.05], [0.02, 0.01, -0.03], [-0.004, 0.002, 0.001]])
    vel = 10.0 + np.stack([np.polyval(np.r_[coef[:, i], 0.0][::-1], t) for i in range(3)], axis=1)
    pos = np.stack([np.polyval(np.polyint(np.r_[coef[:, i], 0.0][::-1]), t) for i in range(3)], axis=1) + 10.0 * t[:, None]
    p, w, _, c = _epochs(rng, n_t, 8, 1, [8] * n_t)
    h, wd, _, _ = _epochs(rng, n_t, 8, 1, [8] * n_t)
    nominal = pos + rng.normal(scale=3.0, size=pos.shape)
    y = np.einsum("tni,ti->tn", p, pos - nominal)  # rows of the truth relative to the nominal, clock 0
    yd = np.einsum("tni,ti->tn", h, vel)
    w[5:8, 2:] = 0.0  # three epochs with two satellites
    sol = solve_kinematic(reduce_epochs(p, w, y, c), reduce_epochs(h, wd, yd), np.diff(nominal, axis=0),
                          np.full(n_t - 1, dt), lag)
    err = np.abs(nominal + sol.z - pos).max()
    # lag 3: 1e-9 m, the trapezoid 7e-4 m
    assert (err < 1e-7) if exact else (err > 1e-4)
