"""The Kalman filter and RTS smoother against the batch solution of the same linear-Gaussian problem."""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.solvers.kalman import kalman_filter, kalman_update, rts_smooth


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
