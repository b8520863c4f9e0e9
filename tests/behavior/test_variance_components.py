"""Variance components of a fixed-kernel projection: Hutchinson redundancies against the exact
trace, and factors that recover the true noise of positions and velocities."""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.behavior.kernel import KernelRepresentation
from gnss_cli.behavior.projection import projection_matrix
from gnss_cli.behavior.variance_components import _redundancy, project_with_variance_components
from gnss_cli.errors import UsageError


def kinematic_kernel(dt: float) -> KernelRepresentation:
    """``x_{t+1} - x_t = dt/2 (v_t + v_{t+1})`` on ``w = (x, v)``, three axes."""
    eye = np.eye(3)
    return KernelRepresentation(np.hstack([-eye, -dt / 2 * eye, eye, -dt / 2 * eye]), q=6)


def _track(n_t: int, dt: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A smooth track (position, velocity) whose kinematic kernel error is tiny (slow sinusoids)."""
    t = np.arange(n_t) * dt
    omega = np.array([0.002, 0.003, 0.0015])
    amp = np.array([400.0, 300.0, 50.0])
    x = amp * np.sin(omega * t[:, None])
    v = amp * omega * np.cos(omega * t[:, None])
    return x, v


def test_hutchinson_redundancies_match_the_exact_trace() -> None:
    n_t = 120
    rng = np.random.default_rng(0)
    cov = np.zeros((n_t, 6, 6))
    cov[:, :3, :3] = np.diag([4.0, 9.0, 16.0])
    cov[:, 3:, 3:] = 0.01 * np.eye(3)
    kernel = kinematic_kernel(1.0)
    p = projection_matrix(kernel, n_t, cov)
    absorbed = np.eye(6 * n_t) - p  # Sigma G^T Gamma^-1 G, acting on vec(w) (epoch-major)
    diag = np.diag(absorbed).reshape(n_t, 6)
    exact = np.array([diag[:, :3].sum(), diag[:, 3:].sum()])
    assert exact.sum() == pytest.approx(3 * (n_t - 1), rel=1e-9)  # one row per constraint
    est = _redundancy(kernel, cov, [slice(0, 3), slice(3, 6)], probes=200, rng=rng)
    np.testing.assert_allclose(est, exact, rtol=0.05)


def test_factors_recover_the_noise_and_beat_the_wrong_a_priori_weights() -> None:
    n_t = 3000
    rng = np.random.default_rng(7)
    x, v = _track(n_t)
    sigma_x, sigma_v = 3.0, 0.05
    w = np.hstack([x + rng.normal(0, sigma_x, x.shape), v + rng.normal(0, sigma_v, v.shape)])
    cov = np.broadcast_to(np.eye(6), (n_t, 6, 6)).copy()  # a priori: both 1 (wrong by 9 and 1/400)
    fit = project_with_variance_components(w, kinematic_kernel(1.0), cov, [slice(0, 3), slice(3, 6)])
    # relative standard error of a variance component: sqrt(2 / redundancy) (8900 and ~65 here)
    assert fit.factors[0] == pytest.approx(sigma_x**2, rel=0.05)
    assert fit.factors[1] == pytest.approx(sigma_v**2, rel=0.5)
    assert fit.redundancy.sum() == pytest.approx(3 * (n_t - 1), rel=0.05)
    err = np.sqrt(np.mean(np.sum((fit.w_hat[:, :3] - x) ** 2, axis=1)))
    from gnss_cli.behavior.projection import misfit

    _, naive = misfit(w, kinematic_kernel(1.0), cov)
    err_naive = np.sqrt(np.mean(np.sum((naive[:, :3] - x) ** 2, axis=1)))
    assert err < 0.5 * err_naive
    # the expected error of a random walk anchored by noisy fixes: sqrt(sigma_x sigma_v dt / 2) per axis
    assert err < 3 * np.sqrt(3 * sigma_x * sigma_v / 2)


def test_noise_free_positions_are_kept_exactly() -> None:
    """With exact positions the factor of the positions collapses and they are returned as given."""
    n_t = 500
    x, v = _track(n_t)
    rng = np.random.default_rng(1)
    w = np.hstack([x, v + rng.normal(0, 0.05, v.shape)])
    fit = project_with_variance_components(w, kinematic_kernel(1.0), np.broadcast_to(np.eye(6), (n_t, 6, 6)).copy(),
                                           [slice(0, 3), slice(3, 6)], max_iter=20)
    assert np.abs(fit.w_hat[:, :3] - x).max() < 1e-3


def test_bad_arguments_are_usage_errors() -> None:
    w = np.zeros((10, 6))
    with pytest.raises(UsageError, match="cov"):
        project_with_variance_components(w, kinematic_kernel(1.0), np.zeros((10, 3, 3)), [slice(0, 3)])
    with pytest.raises(UsageError, match="groups"):
        project_with_variance_components(w, kinematic_kernel(1.0), np.broadcast_to(np.eye(6), (10, 6, 6)).copy(),
                                         [slice(0, 0)])
