"""The Kalman filter and RTS smoother against the batch solution of the same linear-Gaussian problem."""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.solvers.kalman import (FreeRows, clone_prior, clone_transition, free_update, kalman_filter, kalman_update,
                                   rts_smooth)


def _problem(seed: int, T: int = 25, m: int = 4):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    F = np.stack([np.eye(m) + np.diag(rng.uniform(0.2, 1.2, m - 1), 1) for _ in range(T)])  # varying steps
    B = rng.normal(size=(m, m))
    Q1 = 0.05 * B @ B.T + 0.01 * np.eye(m)
    Q = np.repeat(Q1[None], T, axis=0)
    m0, P0 = rng.normal(size=m), np.diag(rng.uniform(1.0, 9.0, m))
    H = [rng.normal(size=(int(rng.integers(0, 4)), m)) for _ in range(T)]  # 0 to 3 rows, some steps none
    y = [rng.normal(scale=3.0, size=h.shape[0]) for h in H]
    r = [rng.uniform(0.2, 2.0, size=h.shape[0]) for h in H]
    return m0, P0, F, Q, H, y, r


def _batch(m0, P0, F, Q, H, y, r):  # type: ignore[no-untyped-def]
    """MAP estimate of all states at once: whitened stacked least squares, and its covariance."""
    T, m = F.shape[0], m0.size
    N = T * m

    def block(t: int) -> np.ndarray:
        out = np.zeros((m, N))
        out[:, t * m:(t + 1) * m] = np.eye(m)
        return out

    w0 = np.linalg.cholesky(np.linalg.inv(P0)).T
    rows, rhs = [w0 @ block(0)], [w0 @ m0]
    for t in range(1, T):
        wq = np.linalg.cholesky(np.linalg.inv(Q[t])).T
        rows.append(wq @ (block(t) - F[t] @ block(t - 1)))
        rhs.append(np.zeros(m))
    for t in range(T):
        if H[t].shape[0]:
            rows.append(H[t] / np.sqrt(r[t])[:, None] @ block(t))
            rhs.append(y[t] / np.sqrt(r[t]))
    M, b = np.vstack(rows), np.concatenate(rhs)
    x = np.linalg.lstsq(M, b, rcond=None)[0].reshape(T, m)
    cov = np.linalg.inv(M.T @ M)
    return x, np.stack([cov[t * m:(t + 1) * m, t * m:(t + 1) * m] for t in range(T)])


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_rts_smoother_equals_the_batch_map_estimate(seed):
    m0, P0, F, Q, H, y, r = _problem(seed)
    res = kalman_filter(m0, P0, F, Q, H, y, r)
    xs, Ps = rts_smooth(res, F)
    xb, Pb = _batch(m0, P0, F, Q, H, y, r)
    assert np.abs(xs - xb).max() < 1e-9 * max(1.0, np.abs(xb).max())
    assert np.abs(Ps - Pb).max() < 1e-9 * np.abs(Pb).max()
    # the filter's last step already uses every measurement: it equals the smoother there
    assert np.allclose(res.x[-1], xb[-1], atol=1e-9) and not np.allclose(res.x[0], xb[0], atol=1e-3)


def test_filtered_estimate_equals_the_batch_solution_of_the_data_so_far():
    m0, P0, F, Q, H, y, r = _problem(4, T=12)
    res = kalman_filter(m0, P0, F, Q, H, y, r)
    for t in (0, 5, 11):
        xb, Pb = _batch(m0, P0, F[: t + 1], Q[: t + 1], H[: t + 1], y[: t + 1], r[: t + 1])
        assert np.allclose(res.x[t], xb[t], atol=1e-9) and np.allclose(res.P[t], Pb[t], atol=1e-9)


def test_joseph_update_equals_the_information_form_and_stays_symmetric():
    rng = np.random.default_rng(9)
    B = rng.normal(size=(5, 5))
    P = B @ B.T + np.eye(5)
    H = rng.normal(size=(7, 5))
    r = rng.uniform(0.1, 1.0, 7)
    x0, y = rng.normal(size=5), rng.normal(size=7)
    x, P1, nu = kalman_update(x0, P, H, y, r)
    info = np.linalg.inv(P) + H.T @ (H / r[:, None])
    assert np.allclose(P1, np.linalg.inv(info), atol=1e-12) and np.array_equal(P1, P1.T)
    assert np.allclose(x, x0 + np.linalg.solve(info, H.T @ ((y - H @ x0) / r)), atol=1e-12)
    assert np.allclose(nu, y - H @ x0)
    same = kalman_update(x0, P, np.zeros((0, 5)), np.zeros(0), np.zeros(0))
    assert np.array_equal(same[0], x0) and np.array_equal(same[1], P)


def test_innovation_gate_drops_only_the_outlying_row():
    rng = np.random.default_rng(3)
    P = np.diag([4.0, 4.0, 1.0])
    H = rng.normal(size=(5, 3))
    r = np.full(5, 0.25)
    x0 = np.zeros(3)
    y = H @ np.array([1.0, -1.0, 0.5]) + rng.normal(scale=0.5, size=5)
    y_bad = y.copy()
    y_bad[2] += 100.0
    x, P1, nu = kalman_update(x0, P, H, y_bad, r, gate=3.29)
    keep = np.arange(5) != 2
    x_ref, P_ref, _ = kalman_update(x0, P, H[keep], y[keep], r[keep])
    assert np.isnan(nu[2]) and np.isfinite(nu[keep]).all()
    assert np.allclose(x, x_ref) and np.allclose(P1, P_ref)
    x_all, _, _ = kalman_update(x0, P, H, y_bad, r)
    assert np.linalg.norm(x_all - x_ref) > 1.0  # without the gate the outlier pulls the state
    # most rows far off: the prior is what is wrong (an unexpected manoeuvre), every row is used
    y_shift = y + 100.0
    x_s, _, nu_s = kalman_update(x0, P, H, y_shift, r, gate=3.29)
    assert np.isfinite(nu_s).all() and np.allclose(x_s, kalman_update(x0, P, H, y_shift, r)[0])


def _difference_problem(seed: int, T: int = 20, m: int = 4, p: int = 2):  # type: ignore[no-untyped-def]
    """A random problem with, at every step t >= 1, rows on ``[x_t, x_{t-1}[:2]]`` with ``p`` free
    nuisance parameters (each row has one: the column of its group)."""
    m0, P0, F, Q, H, y, r = _problem(seed, T, m)
    rng = np.random.default_rng(seed + 100)
    diff = [None]
    for _ in range(1, T):
        n = int(rng.integers(0, 6))
        A = rng.normal(size=(n, m + 2))
        G = np.zeros((n, p))
        G[np.arange(n), rng.integers(0, p, n)] = 1.0
        diff.append((A, rng.normal(scale=3.0, size=n), rng.uniform(0.01, 0.5, n), G))
    return m0, P0, F, Q, H, y, r, diff


def _batch_with_differences(m0, P0, F, Q, H, y, r, diff):  # type: ignore[no-untyped-def]
    """Batch MAP estimate over every state and every step's nuisance parameters (no prior: columns
    without a prior row), whitened stacked least squares; the state blocks of the covariance."""
    T, m = F.shape[0], m0.size
    p = diff[1][3].shape[1]
    N = T * m + T * p

    def block(t: int) -> np.ndarray:
        out = np.zeros((m, N))
        out[:, t * m:(t + 1) * m] = np.eye(m)
        return out

    w0 = np.linalg.cholesky(np.linalg.inv(P0)).T
    rows, rhs = [w0 @ block(0)], [w0 @ m0]
    for t in range(1, T):
        wq = np.linalg.cholesky(np.linalg.inv(Q[t])).T
        rows += [wq @ (block(t) - F[t] @ block(t - 1))]
        rhs += [np.zeros(m)]
    for t in range(T):
        if H[t].shape[0]:
            rows += [H[t] / np.sqrt(r[t])[:, None] @ block(t)]
            rhs += [y[t] / np.sqrt(r[t])]
        if t and diff[t][0].shape[0]:
            A, yd, rd, G = diff[t]
            row = A[:, :m] @ block(t) + A[:, m:] @ block(t - 1)[:2]
            row[:, T * m + t * p:T * m + (t + 1) * p] = G
            rows += [row / np.sqrt(rd)[:, None]]
            rhs += [yd / np.sqrt(rd)]
    M, b = np.vstack(rows), np.concatenate(rhs)
    used = np.any(M != 0.0, axis=0)  # nuisance columns of groups without rows: not estimable, dropped
    sol = np.zeros(N)
    sol[used] = np.linalg.lstsq(M[:, used], b, rcond=None)[0]
    cov = np.linalg.inv(M[:, used].T @ M[:, used])[: T * m, : T * m]
    return sol[: T * m].reshape(T, m), np.stack([cov[t * m:(t + 1) * m, t * m:(t + 1) * m] for t in range(T)])


@pytest.mark.parametrize("seed", [5, 6])
def test_rts_with_cloned_states_and_free_nuisance_equals_the_batch_solution(seed):
    m0, P0, F, Q, H, y, r, diff = _difference_problem(seed)
    m, cloned = m0.size, np.arange(2)
    Fa, Qa = clone_transition(F, Q, cloned)
    ma, Pa = clone_prior(m0, P0, cloned)
    Ha = [np.hstack([h, np.zeros((h.shape[0], 2))]) for h in H]
    free = [None] + [FreeRows(A, yd, rd, G) for A, yd, rd, G in diff[1:]]
    res = kalman_filter(ma, Pa, Fa, Qa, Ha, y, r, free=free)
    xs, Ps = rts_smooth(res, Fa)
    xb, Pb = _batch_with_differences(m0, P0, F, Q, H, y, r, diff)
    assert np.abs(xs[:, :m] - xb).max() < 1e-8 * max(1.0, np.abs(xb).max())
    assert np.abs(Ps[:, :m, :m] - Pb).max() < 1e-8 * np.abs(Pb).max()
    assert np.abs(xs[1:, m:] - xb[:-1, :2]).max() < 1e-8 * max(1.0, np.abs(xb).max())  # the clone is x_{t-1}
    # the difference rows matter: without them the answer is another
    plain = rts_smooth(kalman_filter(m0, P0, F, Q, H, y, r), F)[0]
    assert np.abs(plain - xb).max() > 1e-2


def test_free_update_equals_joint_least_squares_and_its_w_test_the_leave_one_out_innovation():
    rng = np.random.default_rng(21)
    m, n, p = 3, 7, 2
    B = rng.normal(size=(m, m))
    P = B @ B.T + np.eye(m)
    x0 = rng.normal(size=m)
    H, y, r = rng.normal(size=(n, m)), rng.normal(size=n), rng.uniform(0.1, 1.0, n)
    G = np.zeros((n, p))
    G[np.arange(n), [0, 0, 0, 1, 1, 1, 1]] = 1.0
    x, P1, w = free_update(x0, P, FreeRows(H, y, r, G))

    def joint(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """[x, c] from the prior and ``rows``, information form (c without prior); its covariance."""
        A = np.hstack([H[rows], G[rows]]) / np.sqrt(r[rows])[:, None]
        info = A.T @ A
        info[:m, :m] += np.linalg.inv(P)
        rhs = A.T @ (y[rows] / np.sqrt(r[rows]))
        rhs[:m] += np.linalg.solve(P, x0)
        cov = np.linalg.inv(info)
        return cov @ rhs, cov

    theta, cov = joint(np.arange(n))
    assert np.allclose(x, theta[:m], atol=1e-10) and np.allclose(P1, cov[:m, :m], atol=1e-10)
    for i in range(n):
        theta_i, cov_i = joint(np.flatnonzero(np.arange(n) != i))
        a = np.r_[H[i], G[i]]
        loo = (y[i] - a @ theta_i) / np.sqrt(r[i] + a @ cov_i @ a)
        assert w[i] == pytest.approx(loo, abs=1e-9)


def test_free_update_gate_takes_out_a_jump_the_prediction_cannot_see():
    """Rows precise to 1 cm on a state known to 10 m: a 0.2 m error in one row is 0.02 sigma of its
    innovation against the prior but 20 sigma against the other rows; the gate takes it out, alone."""
    rng = np.random.default_rng(8)
    P, x_true = 100.0 * np.eye(3), np.array([1.0, -2.0, 0.5])
    H = rng.normal(size=(8, 3))
    G = np.ones((8, 1))
    r = np.full(8, 1e-4)
    y = H @ x_true + 3.0 + rng.normal(scale=1e-2, size=8)
    y[4] += 0.2
    S = H @ P @ H.T + np.diag(r)
    assert abs(0.2 / np.sqrt(S[4, 4])) < 0.05
    x, _, w = free_update(np.zeros(3), P, FreeRows(H, y, r, G), gate=3.29)
    keep = np.arange(8) != 4
    x_ref, P_ref, _ = free_update(np.zeros(3), P, FreeRows(H[keep], y[keep], r[keep], G[keep]))
    assert np.isnan(w[4]) and np.isfinite(w[keep]).all() and np.abs(w[keep]).max() <= 3.29
    assert np.allclose(x, x_ref) and np.linalg.norm(x - x_true) < 0.05
    x_all, _, _ = free_update(np.zeros(3), P, FreeRows(H, y, r, G))
    assert np.linalg.norm(x_all - x_true) > 2 * np.linalg.norm(x - x_true)


def test_rule_of_the_half_applies_per_group():
    """Group 0: one outlier of five, taken out; group 1: three of four far off (the prior, not the
    data, is wrong there), all four used."""
    rng = np.random.default_rng(4)
    P, x0 = np.eye(2), np.zeros(2)
    H = rng.normal(size=(9, 2))
    r = np.full(9, 0.01)
    y = H @ np.array([0.3, -0.2]) + rng.normal(scale=0.1, size=9)
    y[1] += 50.0
    y[6:] += 50.0
    groups = np.array([0, 0, 0, 0, 0, 1, 1, 1, 1])
    _, _, nu = kalman_update(x0, P, H, y, r, gate=3.29, groups=groups)
    assert np.flatnonzero(np.isnan(nu)).tolist() == [1]
    _, _, nu_one = kalman_update(x0, P, H, y, r, gate=3.29)  # one group: 4 of 9 out, all taken out
    assert np.flatnonzero(np.isnan(nu_one)).tolist() == [1, 6, 7, 8]
