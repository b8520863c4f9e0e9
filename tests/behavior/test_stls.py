"""Identification by STLS: exact data, seeded Monte Carlo, shared kernels, covariances."""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.behavior import KernelRepresentation, StlsStatus, misfit, stls, wtls
from gnss_cli.errors import UsageError

from behavior_trajectories import (
    arc_polynomial,
    circular_arc,
    damped_sinusoids,
    draw_noise,
    nine_mode_series,
    quadratic,
    random_covariances,
    weighted_norm2,
)

TRAIN = 30
HORIZON = 15


def exact_cases() -> list[tuple[str, np.ndarray, str]]:
    rng = np.random.default_rng(5)
    return [
        ("quadratic", quadratic(TRAIN + HORIZON), "shared"),
        ("arc", circular_arc(TRAIN + HORIZON, 0.07), "shared"),
        ("damped", damped_sinusoids(TRAIN + HORIZON), "shared"),
        ("nine-mode", nine_mode_series(TRAIN + HORIZON, rng), "full"),
    ]


@pytest.mark.parametrize(("name", "w", "structure"), exact_cases(), ids=lambda x: x if isinstance(x, str) else "")
def test_exact_data_is_fitted_and_continued(name: str, w: np.ndarray, structure: str) -> None:
    train = w[:TRAIN]
    res = stls(train, lag=3, structure=structure)
    assert res.success, res.message
    assert res.misfit <= 1e-12 * np.sum(train**2)
    assert res.kernel.annihilates(w, rtol=1e-10)  # also the samples it never saw
    pred = res.kernel.predict(res.w_hat[-3:], HORIZON)
    assert np.linalg.norm(pred - w[TRAIN:]) <= 1e-8 * np.linalg.norm(w[TRAIN:])


@pytest.mark.parametrize("w", [quadratic(TRAIN), circular_arc(TRAIN, 0.07)], ids=["quadratic", "arc"])
def test_exact_low_rank_data_with_the_full_kernel(w: np.ndarray) -> None:
    """Hankel rank 3 < 9: the order-9 kernel is not unique, but any optimum annihilates the data.

    (Prediction is not checked: the extra poles of a non-unique kernel are arbitrary.)
    """
    res = stls(w, lag=3)
    assert res.success and res.misfit <= 1e-12 * np.sum(w**2)
    assert res.kernel.annihilates(w, rtol=1e-10)


def _check_noisy_trial(w: np.ndarray, cov: np.ndarray, true_kernel: KernelRepresentation, **kw: object) -> None:
    res = stls(w, cov=cov, **kw)  # type: ignore[arg-type]
    base = wtls(w, cov=cov, **kw)  # type: ignore[arg-type]
    m_true, _ = misfit(w, true_kernel, cov)
    assert res.success, res.message
    assert res.misfit <= m_true * (1 + 1e-10)
    assert res.misfit <= base.misfit * (1 + 1e-10)
    r = res.kernel
    assert np.linalg.norm(r.residual(res.w_hat)) <= 1e-9 * np.linalg.norm(r.R) * np.linalg.norm(res.w_hat)
    assert weighted_norm2(w - res.w_hat, cov) == pytest.approx(res.misfit, rel=1e-9)


@pytest.mark.parametrize("seed", range(50))
def test_monte_carlo_full_kernel_order_9(seed: int) -> None:
    """Noise 0.03 on a series of amplitude ~1: a single descent from the WTLS kernel ends in a
    local minimum in some of these trials; the subspace, mirrored and modal starts (none of
    which uses the true kernel) reach a misfit below the true kernel's in every one."""
    rng = np.random.default_rng(seed)
    exact = nine_mode_series(60, np.random.default_rng(1000))
    k_true = stls(exact, lag=3).kernel  # exact data: the unique order-9 behavior
    cov = random_covariances(60, rng, 0.03)
    _check_noisy_trial(exact + draw_noise(cov, rng), cov, k_true, lag=3)


@pytest.mark.parametrize("seed", range(50))
def test_monte_carlo_lag1_order3_arc(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    omega = 2 * np.pi / 50
    exact = circular_arc(80, omega, radius_m=1.0)
    k_true = stls(exact, lag=1, order=3).kernel
    cov = random_covariances(80, rng, 0.05)
    _check_noisy_trial(exact + draw_noise(cov, rng), cov, k_true, lag=1, order=3)


@pytest.mark.parametrize("seed", range(50))
def test_monte_carlo_shared_kernel_on_an_arc(seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    omega = 0.1
    exact = circular_arc(40, omega)
    k_true = KernelRepresentation.shared(arc_polynomial(omega), 3)
    cov = random_covariances(40, rng, 0.1)
    _check_noisy_trial(exact + draw_noise(cov, rng), cov, k_true, lag=3, structure="shared")


@pytest.mark.parametrize("fixed_roots", [(), (1.0,)])
def test_shared_kernel_recovers_the_turn_rate_at_low_noise(fixed_roots: tuple[float, ...]) -> None:
    omega = 0.1
    rng = np.random.default_rng(7)
    exact = circular_arc(60, omega)
    for _ in range(5):
        w = exact + 1e-5 * rng.normal(size=exact.shape)
        res = stls(w, lag=3, structure="shared", fixed_roots=fixed_roots)
        roots = np.roots(res.kernel.shared_coefficients()[::-1])
        for target in (1.0, np.exp(1j * omega), np.exp(-1j * omega)):
            assert np.min(np.abs(roots - target)) < 1e-3


def test_fixed_root_makes_the_fit_translation_invariant() -> None:
    rng = np.random.default_rng(8)
    w = circular_arc(25, 0.15) + 0.05 * rng.normal(size=(25, 3))
    shift = np.array([1000.0, -2000.0, 300.0])
    a = stls(w, lag=3, structure="shared", fixed_roots=(1.0,))
    b = stls(w + shift, lag=3, structure="shared", fixed_roots=(1.0,))
    assert b.misfit == pytest.approx(a.misfit, rel=1e-6)
    np.testing.assert_allclose(b.w_hat - shift, a.w_hat, atol=1e-6)
    np.testing.assert_allclose(b.kernel.shared_coefficients(), a.kernel.shared_coefficients(), atol=1e-6)
    assert abs(np.polyval(a.kernel.shared_coefficients()[::-1], 1.0)) < 1e-12


def test_full_covariance_is_honoured() -> None:
    """Noise 100x larger along one oblique direction: the correction goes along it."""
    rng = np.random.default_rng(9)
    omega = 0.1
    exact = circular_arc(40, omega)
    d = np.array([1.0, 1.0, 1.0]) / np.sqrt(3.0)
    basis = np.linalg.qr(np.column_stack([d, [1.0, 0, 0], [0, 1.0, 0]]))[0]
    sig = basis @ np.diag([1.0, 0.01, 0.01]) ** 2 @ basis.T  # 100x the std along d
    cov = np.broadcast_to(sig, (40, 3, 3)).copy()
    w = exact + draw_noise(cov, rng)
    weighted = stls(w, lag=3, cov=cov, structure="shared")
    plain = stls(w, lag=3, structure="shared")
    corr = w - weighted.w_hat
    across = corr - np.outer(corr @ d, d)
    # the precise directions are barely touched (their noise is 0.01) ...
    assert np.sqrt(np.mean(np.sum(across**2, axis=1))) < 0.02
    # ... and the weighted fit is closer to the truth in them than the unweighted one
    err_w = weighted.w_hat - exact
    err_p = plain.w_hat - exact
    across_w = err_w - np.outer(err_w @ d, d)
    across_p = err_p - np.outer(err_p @ d, d)
    assert np.linalg.norm(across_w) < 0.5 * np.linalg.norm(across_p)
    assert np.linalg.norm(err_w) < np.linalg.norm(err_p)


def test_infeasible_full_order_is_refused() -> None:
    with pytest.raises(UsageError, match="infeasible"):
        stls(np.random.default_rng(0).normal(size=(30, 3)), lag=3, order=6)


def test_order_6_is_feasible_only_for_very_short_windows() -> None:
    """``g = q(l+1) - order = 6`` kernel rows: ``g (T - l) <= q T`` holds only up to ``T = 6``."""
    rng = np.random.default_rng(0)
    w = rng.normal(size=(6, 3))
    for n_t in (7, 20):
        with pytest.raises(UsageError, match=rf"order: infeasible .* 6 kernel rows over T - lag = {n_t - 3} columns"):
            stls(rng.normal(size=(n_t, 3)), lag=3, order=6)
    res = stls(w, lag=3, order=6)  # at the bound: as many constraints as data values, no UsageError
    assert res.kernel.R.shape == (6, 12)
    if res.status == StlsStatus.INFEASIBLE:
        assert not res.success and np.isinf(res.misfit)
        assert res.w_hat is not w and np.array_equal(res.w_hat, w)
    else:  # the zero trajectory satisfies every kernel: the misfit is at most |w|^2
        assert res.success and res.misfit <= float(np.sum(w * w)) * (1 + 1e-12)


def test_bad_arguments() -> None:
    w = np.zeros((10, 3))
    with pytest.raises(UsageError, match="lag"):
        stls(w, lag=0)
    with pytest.raises(UsageError, match="structure"):
        stls(w, lag=2, structure="diagonal")
    with pytest.raises(UsageError, match="order"):
        stls(w, lag=2, order=4, structure="shared")
    with pytest.raises(UsageError, match="samples"):
        stls(w[:3], lag=2)
    with pytest.raises(UsageError, match="conjugate"):
        stls(w, lag=3, structure="shared", fixed_roots=(1j,))


def test_singular_start_is_recovered_not_crashed() -> None:
    """A starting kernel with a singular G Sigma G^T falls back to the next start."""
    rng = np.random.default_rng(3)
    w = circular_arc(30, 0.1) + 0.01 * rng.normal(size=(30, 3))
    bad = np.zeros((3, 12))
    bad[:2, :2] = np.eye(2)
    res = stls(w, lag=3, kernel0=KernelRepresentation(bad, q=3))
    assert res.success and np.isfinite(res.misfit)
