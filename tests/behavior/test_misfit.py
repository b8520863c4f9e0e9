"""The inner problem: banded computation against a dense independent one, and its identities."""

import numpy as np
import pytest

from gnss_cli.behavior import KernelRepresentation, SingularGramError, misfit, projection_matrix
from gnss_cli.errors import NoSolutionError, UsageError

from behavior_trajectories import random_covariances, weighted_norm2


def dense_inner_problem(w: np.ndarray, k: KernelRepresentation, cov: np.ndarray) -> tuple[float, np.ndarray]:
    """``min ||w - w_hat||_{Sigma^-1}`` s.t. ``G w_hat = 0`` by a dense KKT solve."""
    n_t, q = w.shape
    n = n_t - k.lag
    g_mat = np.zeros((n * k.p, n_t * q))
    for j in range(n):
        g_mat[j * k.p : (j + 1) * k.p, j * q : (j + k.lag + 1) * q] = k.R
    sigma = np.zeros((n_t * q, n_t * q))
    for t in range(n_t):
        sigma[t * q : (t + 1) * q, t * q : (t + 1) * q] = cov[t]
    kkt = np.block([[np.linalg.inv(sigma), g_mat.T], [g_mat, np.zeros((n * k.p, n * k.p))]])
    rhs = np.concatenate([np.linalg.solve(sigma, w.ravel()), np.zeros(n * k.p)])
    w_hat = np.linalg.solve(kkt, rhs)[: n_t * q].reshape(n_t, q)
    return weighted_norm2(w - w_hat, cov), w_hat


@pytest.mark.parametrize("form", ["identity", "diag", "full"])
@pytest.mark.parametrize("rows", [1, 2, 3])
def test_banded_misfit_matches_dense_kkt(form: str, rows: int) -> None:
    rng = np.random.default_rng(10 + rows)
    n_t, q, lag = 14, 3, 2
    w = rng.normal(size=(n_t, q))
    k = KernelRepresentation(rng.normal(size=(rows, q * (lag + 1))), q=q)
    full = random_covariances(n_t, rng, 1.0)
    cov = {"identity": None, "diag": np.einsum("tii->ti", full), "full": full}[form]
    dense_cov = {"identity": np.broadcast_to(np.eye(q), (n_t, q, q)), "diag": np.einsum("tii->ti", full)[:, :, None] * np.eye(q), "full": full}[form]
    m, w_hat = misfit(w, k, cov)
    m_ref, w_hat_ref = dense_inner_problem(w, k, dense_cov)
    assert m == pytest.approx(m_ref, rel=1e-9)
    np.testing.assert_allclose(w_hat, w_hat_ref, rtol=1e-8, atol=1e-10 * np.abs(w).max())
    assert k.annihilates(w_hat, rtol=1e-12)
    assert weighted_norm2(w - w_hat, dense_cov) == pytest.approx(m, rel=1e-10)


def test_projection_matrix_is_the_sigma_orthogonal_projector() -> None:
    rng = np.random.default_rng(4)
    n_t = 12
    cov = random_covariances(n_t, rng, 0.5)
    k = KernelRepresentation.pva(3)
    p = projection_matrix(k, n_t, cov)
    w = rng.normal(size=(n_t, 3))
    _, w_hat = misfit(w, k, cov)
    np.testing.assert_allclose(p @ w.ravel(), w_hat.ravel(), atol=1e-10)
    np.testing.assert_allclose(p @ p, p, atol=1e-10)
    sigma = np.zeros((3 * n_t, 3 * n_t))
    for t in range(n_t):
        sigma[3 * t : 3 * t + 3, 3 * t : 3 * t + 3] = cov[t]
    # Sigma-orthogonal: P Sigma is symmetric
    np.testing.assert_allclose(p @ sigma, (p @ sigma).T, atol=1e-10)
    # the smoothed fixes are never less precise than... never *more* uncertain than the raw ones
    cov_hat = p @ sigma @ p.T
    assert np.all(np.diag(cov_hat) <= np.diag(sigma) * (1 + 1e-12))


@pytest.mark.parametrize(("kernel", "n_t"), [(KernelRepresentation.static(3), 20000), (KernelRepresentation.pva(3), 200)])
def test_misfit_long_series_runs_without_dense_matrices(kernel: KernelRepresentation, n_t: int) -> None:
    # PVA: G G^T has condition ~T^6 (triple root at z = 1), so accuracy decays like T^4:
    # 1e-9 relative at T = 200, 4e-7 at 1000, breakdown near 3400. Long series go in windows.
    t = np.arange(n_t, dtype=float)
    rng = np.random.default_rng(0)
    w = np.stack([t, 2 * t, -t], axis=1) + rng.normal(size=(n_t, 3))
    m, w_hat = misfit(w, kernel)
    # misfit equals the squared correction (identity covariance)
    assert np.sum((w - w_hat) ** 2) == pytest.approx(m, rel=1e-8)
    assert kernel.annihilates(w_hat, rtol=1e-10)
    # the PVA projection is the least-squares quadratic fit, computed independently
    if kernel.lag == 3:
        vander = np.vander(t / n_t, 3)
        coef, *_ = np.linalg.lstsq(vander, w, rcond=None)
        np.testing.assert_allclose(w_hat, vander @ coef, atol=1e-6)


def test_singular_gram_is_a_typed_error() -> None:
    # a kernel row that vanishes entirely makes G Sigma G^T singular
    r = np.zeros((3, 6))
    r[:2, :2] = np.eye(2)
    with pytest.raises(SingularGramError) as info:
        misfit(np.ones((6, 3)), KernelRepresentation(r, q=3))
    assert isinstance(info.value, NoSolutionError)


def test_misfit_validates_shapes() -> None:
    with pytest.raises(UsageError, match="cov"):
        misfit(np.zeros((5, 3)), KernelRepresentation.static(3), np.ones((4, 3)))
    with pytest.raises(UsageError, match="positive definite"):
        misfit(np.zeros((5, 3)), KernelRepresentation.static(3), -np.broadcast_to(np.eye(3), (5, 3, 3)))
    with pytest.raises(UsageError, match="q=3"):
        misfit(np.zeros((5, 2)), KernelRepresentation.static(3))
