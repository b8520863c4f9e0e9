"""M-estimators by IRLS (gnss_cli.solvers.robust): the weight functions, and the estimate
against scipy.optimize.least_squares with the same robust loss."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from gnss_cli.errors import UsageError
from gnss_cli.solvers.robust import DEFAULT_TUNING, m_estimator_rho, m_estimator_weights, irls_batch


def _problem(seed: int, n: int = 9, m: int = 4, outlier: float = 40.0):
    rng = np.random.default_rng(seed)
    A = np.column_stack([rng.normal(size=(n, m - 1)), np.ones(n)])
    sigma = rng.uniform(0.5, 3.0, n)
    q = A @ rng.normal(size=m) + sigma * rng.normal(size=n)
    q[2] += outlier * sigma[2]
    return A, q, sigma


@pytest.mark.parametrize("estimator", ["huber", "cauchy"])
def test_psi_is_the_derivative_of_rho(estimator):
    """w(u) u = psi(u) = rho'(u), checked by central differences."""
    u = np.linspace(-12.0, 12.0, 97)
    h = 1e-6
    drho = (m_estimator_rho(u + h, estimator) - m_estimator_rho(u - h, estimator)) / (2 * h)
    np.testing.assert_allclose(m_estimator_weights(u, estimator) * u, drho, atol=1e-6)


def test_huber_weights_are_one_inside_k_and_k_over_u_outside():
    k = DEFAULT_TUNING["huber"]
    u = np.array([0.0, 0.5 * k, -k, 2 * k, -10 * k])
    np.testing.assert_allclose(m_estimator_weights(u, "huber"), [1.0, 1.0, 1.0, 0.5, 0.1])
    c = DEFAULT_TUNING["cauchy"]
    np.testing.assert_allclose(m_estimator_weights(np.array([0.0, c, 3 * c]), "cauchy"), [1.0, 0.5, 0.1])


@pytest.mark.parametrize("estimator", ["huber", "cauchy"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_irls_equals_scipy_least_squares_with_the_robust_loss(estimator, seed):
    """scipy minimizes 0.5 f_scale^2 sum rho_s((f / f_scale)^2) with f = (q - A x) / sigma:
    for loss='huber' / 'cauchy' and f_scale = k / c that is sum rho(u) of the module table."""
    A, q, sigma = _problem(seed)
    k = DEFAULT_TUNING[estimator]
    fit = irls_batch(A[None], q[None], np.ones((1, q.size), bool), sigma[None], estimator=estimator,
                           tolerance=1e-13, max_iterations=500)
    assert fit.converged[0]
    x0 = np.linalg.lstsq(A / sigma[:, None], q / sigma, rcond=None)[0]
    ref = least_squares(lambda x: (q - A @ x) / sigma, x0, loss=estimator, f_scale=k, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    np.testing.assert_allclose(fit.x[0], ref.x, atol=1e-6)
    # the outlier is the row with the smallest weight, and it pulled plain least squares away
    assert np.argmin(fit.weights[0]) == 2 and fit.weights[0, 2] < 0.1
    assert np.linalg.norm(x0 - ref.x) > 100 * np.linalg.norm(fit.x[0] - ref.x)


def test_unweighted_irls_solves_its_estimating_equations():
    """weighted=False: sum_i sigma_i psi(u_i) a_i = 0 (unit a-priori weights, u = r / sigma)."""
    A, q, sigma = _problem(5)
    fit = irls_batch(A[None], q[None], np.ones((1, q.size), bool), sigma[None], estimator="huber",
                           weighted=False, tolerance=1e-13, max_iterations=500)
    u = (q - A @ fit.x[0]) / sigma
    psi = m_estimator_weights(u, "huber") * u
    np.testing.assert_allclose(A.T @ (sigma * psi), 0.0, atol=1e-8)
    weighted = irls_batch(A[None], q[None], np.ones((1, q.size), bool), sigma[None], estimator="huber")
    assert np.linalg.norm(weighted.x[0] - fit.x[0]) > 1e-3  # a different problem


def test_epochs_are_independent_and_masked_rows_ignored():
    problems = [_problem(s) for s in range(4)]
    A = np.stack([p[0] for p in problems])
    q = np.stack([p[1] for p in problems])
    sigma = np.stack([p[2] for p in problems])
    mask = np.ones(q.shape, bool)
    mask[1, 5] = False
    q_junk = q.copy()
    q_junk[1, 5] = 1e9  # a masked row's value does not matter
    batch = irls_batch(A, q_junk, mask, sigma, estimator="cauchy")
    assert np.isnan(batch.weights[1, 5])
    for t in range(4):
        one = irls_batch(A[t:t + 1], q[t:t + 1], mask[t:t + 1], sigma[t:t + 1], estimator="cauchy")
        np.testing.assert_allclose(batch.x[t], one.x[0], atol=1e-9)


def test_rows_not_reweighted_keep_weight_one():
    A, q, sigma = _problem(3)
    keep = np.ones((1, q.size), bool)
    keep[0, 2] = False  # the outlier row is exact by declaration: no down-weighting
    fit = irls_batch(A[None], q[None], np.ones((1, q.size), bool), sigma[None], estimator="huber", reweight=keep)
    assert fit.weights[0, 2] == 1.0


@pytest.mark.parametrize("kwargs", [{"estimator": "tukey"}, {"estimator": "huber", "tuning": -1.0},
                                    {"estimator": "huber", "tolerance": 0.0}, {"estimator": "huber", "max_iterations": 0}])
def test_bad_options_are_usage_errors(kwargs):
    A, q, sigma = _problem(0)
    with pytest.raises(UsageError):
        irls_batch(A[None], q[None], np.ones((1, q.size), bool), sigma[None], **kwargs)
