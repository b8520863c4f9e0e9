"""Per-method identities of DESIGN.md section 3, checked by independent computations."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize
from solver_cases import sky_matrix

from gnss_cli.solvers import Status, solve, solve_batch
from gnss_cli.solvers.stls import stls_misfit


def _noisy(rng: np.random.Generator, n: int, sigma_a: float = 0.03, sigma_q: float = 1.0):
    A = sky_matrix(rng, n)
    x_true = rng.normal(0.0, 20.0, 4)
    q = A @ x_true + rng.normal(0.0, sigma_q, n)
    A[:, :3] += rng.normal(0.0, sigma_a, (n, 3))
    return A, q


# ---------------------------------------------------------------- TLS


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(5, 12))
def test_tls_equals_svd_solution_and_closed_form(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    A, q = _noisy(rng, n)
    res = solve("tls", A, q)
    assert res.success
    C = np.column_stack([A, q])
    _, s, vt = np.linalg.svd(C)  # full SVD of the augmented matrix, independent of the solver's QR
    v = vt[-1]
    np.testing.assert_allclose(res.x, -v[:4] / v[4], rtol=1e-8, atol=1e-8)
    closed = np.linalg.solve(A.T @ A - s[-1] ** 2 * np.eye(4), A.T @ q)
    np.testing.assert_allclose(res.x, closed, rtol=1e-7, atol=1e-7)
    assert res.details.sigma_min == pytest.approx(s[-1], rel=1e-10)
    assert res.cost == pytest.approx(s[-1] ** 2, rel=1e-10)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(5, 12))
def test_tls_corrected_system_holds_and_correction_norm_is_sigma_min(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    A, q = _noisy(rng, n)
    res = solve("tls", A, q)
    C = np.column_stack([A, q])
    z = np.r_[res.x, -1.0]
    dC = -np.outer(C @ z, z) / (z @ z)  # the rank-one TLS correction
    dA, dq = dC[:, :4], dC[:, 4]
    np.testing.assert_allclose((A + dA) @ res.x, q + dq, rtol=0, atol=1e-9 * np.abs(q).max())
    sigma_min = np.linalg.svd(C, compute_uv=False)[-1]
    assert np.linalg.norm(dC, "fro") == pytest.approx(sigma_min, rel=1e-8)


def test_tls_nongeneric_is_reported_not_garbage() -> None:
    # σ_min(A) = 1 = σ_min([A q]): the TLS solution does not exist
    A = np.array([[2.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
    q = np.array([0.0, 0.0, 1.0])
    res = solve("tls", A, q)
    assert res.status == Status.NONGENERIC and not res.success
    assert np.isnan(res.x).all()
    # same for the weighted variant, and in a batch beside a good epoch
    good_A = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    batch = solve_batch("wtls", np.stack([A, good_A]), np.stack([q, good_A @ np.array([1.0, 2.0])]))
    assert batch.status.tolist() == [Status.NONGENERIC, Status.CONVERGED]


# ---------------------------------------------------------------- DLS


def test_dls_corrected_system_holds_and_correction_is_minimal() -> None:
    rng = np.random.default_rng(11)
    for _ in range(8):
        n = int(rng.integers(5, 9))
        A, q = _noisy(rng, n, sigma_a=0.05, sigma_q=0.5)
        res = solve("dls", A, q)
        assert res.success
        x = res.x
        dA = -np.outer(A @ x - q, x) / (x @ x)  # smallest ΔA with (A + ΔA) x = q for this x
        np.testing.assert_allclose((A + dA) @ x, q, rtol=0, atol=1e-9 * np.abs(q).max())
        assert np.linalg.norm(dA, "fro") ** 2 == pytest.approx(res.cost, rel=1e-8)

        # brute force: minimize ||A y - q||²/||y||² over y from many random starts
        def misfit(y: np.ndarray) -> float:
            return float(np.sum((A @ y - q) ** 2) / (y @ y))

        starts = [res.x * rng.uniform(0.5, 1.5) + rng.normal(0, 10, 4) for _ in range(10)]
        best = min(minimize(misfit, y0, method="BFGS", options={"gtol": 1e-12}).fun for y0 in starts)
        assert res.cost <= best * (1 + 1e-7)
        assert best <= res.cost * (1 + 1e-5)  # the brute force finds the same minimum


# ---------------------------------------------------------------- MTLS


def test_mtls_equals_ls_when_every_column_is_exact_and_tls_when_none() -> None:
    rng = np.random.default_rng(12)
    A = np.stack([_noisy(rng, 9)[0] for _ in range(5)])
    q = np.stack([_noisy(rng, 9)[1] for _ in range(5)])
    ls = solve_batch("ls", A, q)
    tls = solve_batch("tls", A, q)
    all_exact = solve_batch("mtls", A, q, exact_columns=[0, 1, 2, 3])
    none_exact = solve_batch("mtls", A, q)
    np.testing.assert_allclose(all_exact.x, ls.x, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(all_exact.cov, ls.cov, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(all_exact.cost, ls.cost, rtol=1e-9)
    np.testing.assert_allclose(none_exact.x, tls.x, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(none_exact.cov, tls.cov, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(none_exact.cost, tls.cost, rtol=1e-9)


def test_mtls_cost_is_the_smallest_correction_of_the_noisy_columns() -> None:
    rng = np.random.default_rng(13)
    A, q = _noisy(rng, 8)
    res = solve("mtls", A, q, exact_columns=[3])
    x = res.x
    z = np.r_[x[:3], -1.0]  # noisy unknowns and -1 for q
    r = A @ x - q
    dN = -np.outer(r, z) / (z @ z)  # minimal [ΔA_N Δq] making the row constraints hold
    np.testing.assert_allclose((A[:, :3] + dN[:, :3]) @ x[:3] + A[:, 3] * x[3], q + dN[:, 3], atol=1e-9)
    assert np.linalg.norm(dN, "fro") ** 2 == pytest.approx(res.cost, rel=1e-8)


# ---------------------------------------------------------------- STLS


def test_stls_equals_wls_when_geometry_covariance_is_zero() -> None:
    rng = np.random.default_rng(14)
    T, n = 4, 9
    A = np.stack([_noisy(rng, n)[0] for _ in range(T)])
    q = np.stack([_noisy(rng, n)[1] for _ in range(T)])
    var_q = rng.uniform(0.5, 4.0, (T, n))
    S = np.zeros((T, n, 4, 4))
    S[:, :, 3, 3] = var_q
    stls = solve_batch("stls", A, q, exact_columns=[3], row_cov=S)
    wls = solve_batch("wls", A, q, weights=1.0 / var_q)
    assert stls.success.all()
    np.testing.assert_allclose(stls.x, wls.x, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(stls.cov, wls.cov, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(stls.cost, wls.cost, rtol=1e-9)


def test_stls_equals_mtls_when_row_cov_is_scaled_identity() -> None:
    rng = np.random.default_rng(15)
    T, n = 4, 9
    A = np.stack([_noisy(rng, n)[0] for _ in range(T)])
    q = np.stack([_noisy(rng, n)[1] for _ in range(T)])
    s2 = 2.5
    S = np.broadcast_to(s2 * np.eye(4), (T, n, 4, 4))
    stls = solve_batch("stls", A, q, exact_columns=[3], row_cov=S)
    mtls = solve_batch("mtls", A, q, exact_columns=[3])
    np.testing.assert_allclose(stls.x, mtls.x, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(stls.cov, s2 * mtls.cov, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(stls.cost * s2, mtls.cost, rtol=1e-8)


def _random_row_cov(rng: np.random.Generator, T: int, n: int) -> np.ndarray:
    L = rng.normal(0.0, 1.0, (T, n, 4, 4)) * np.array([0.02, 0.02, 0.02, 1.0])[:, None]
    return L @ np.swapaxes(L, -1, -2) + np.diag([0.0, 0.0, 0.0, 0.3])


def test_stls_with_general_row_cov_minimizes_the_misfit_and_matches_scipy() -> None:
    rng = np.random.default_rng(16)
    T, n = 5, 8
    A = np.stack([_noisy(rng, n, sigma_a=0.05)[0] for _ in range(T)])
    q = np.stack([_noisy(rng, n)[1] for _ in range(T)])
    S = _random_row_cov(rng, T, n)
    newton = solve_batch("stls", A, q, exact_columns=[3], row_cov=S)
    scipy_ = solve_batch("stls", A, q, exact_columns=[3], row_cov=S, optimizer="scipy")
    assert newton.success.all() and scipy_.success.all()
    np.testing.assert_allclose(newton.x, scipy_.x, rtol=1e-7, atol=1e-7)
    used = np.ones((T, n), dtype=bool)
    M0 = stls_misfit(newton.x, A, q, used, S, (3,))
    np.testing.assert_allclose(M0, newton.cost, rtol=1e-12)
    for _ in range(20):  # no nearby point has a lower misfit
        M1 = stls_misfit(newton.x + rng.normal(0.0, 1e-3, (T, 4)), A, q, used, S, (3,))
        assert np.all(M1 >= M0 * (1 - 1e-12))
    # the misfit it reaches is never worse than WLS (its own starting point)
    wls = solve_batch("wls", A, q, weights=1.0 / S[:, :, 3, 3])
    assert np.all(newton.cost <= stls_misfit(wls.x, A, q, used, S, (3,)) * (1 + 1e-12))


def test_stls_gain_matches_finite_differences_with_general_row_cov() -> None:
    rng = np.random.default_rng(17)
    T, n = 4, 8
    A = np.stack([_noisy(rng, n, sigma_a=0.05)[0] for _ in range(T)])
    q = np.stack([_noisy(rng, n)[1] for _ in range(T)])
    S = _random_row_cov(rng, T, n)
    res = solve_batch("stls", A, q, exact_columns=[3], row_cov=S)
    h = 1e-5
    for i in range(n):
        qp, qm = q.copy(), q.copy()
        qp[:, i] += h
        qm[:, i] -= h
        fd = (
            solve_batch("stls", A, qp, exact_columns=[3], row_cov=S).x
            - solve_batch("stls", A, qm, exact_columns=[3], row_cov=S).x
        ) / (2 * h)
        np.testing.assert_allclose(res.gain[:, :, i], fd, rtol=1e-5, atol=1e-7)
    # cov is the gain weighted by the pseudorange variances
    expected = np.einsum("tmn,tn,tkn->tmk", res.gain, S[:, :, 3, 3], res.gain)
    np.testing.assert_allclose(res.cov, expected, rtol=1e-10, atol=1e-14)


# ---------------------------------------------------------------- WTLS


def test_wtls_is_tls_of_the_whitened_system() -> None:
    rng = np.random.default_rng(18)
    A, q = _noisy(rng, 9)
    w = rng.uniform(0.2, 5.0, 9)
    res = solve("wtls", A, q, weights=w)
    ref = solve("tls", np.sqrt(w)[:, None] * A, np.sqrt(w) * q)
    np.testing.assert_allclose(res.x, ref.x, rtol=1e-10, atol=1e-10)
    # the gain with respect to raw q is the whitened gain times sqrt(w); cov is identical
    np.testing.assert_allclose(res.gain, ref.gain * np.sqrt(w), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(res.cov, ref.cov, rtol=1e-9, atol=1e-13)
    # unit weights: plain TLS
    np.testing.assert_allclose(solve("wtls", A, q).x, solve("tls", A, q).x, rtol=1e-12, atol=1e-12)


def test_wtls_column_scale_is_tls_of_the_scaled_matrix() -> None:
    rng = np.random.default_rng(19)
    A, q = _noisy(rng, 9)
    d = np.array([2.0, 0.5, 1.5, 3.0, 0.8])
    res = solve("wtls", A, q, column_scale=d)
    C = np.column_stack([A, q]) * d
    v = np.linalg.svd(C)[2][-1]
    x_scaled = -v[:4] / v[4]
    np.testing.assert_allclose(res.x, d[:4] * x_scaled / d[4], rtol=1e-9, atol=1e-9)
