"""Batched windows: the same fits as the per-series STLS and projection, window by window."""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.behavior import KernelRepresentation, StlsStatus, misfit, stls
from gnss_cli.behavior.batch import identify_windows, project_windows
from gnss_cli.errors import UsageError

from behavior_trajectories import circular_arc, draw_noise, random_covariances, weighted_norm2


def _noisy_windows(n_win: int, n_t: int, noise: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    arc = circular_arc(n_win + n_t, 0.08)
    cov = np.stack([random_covariances(n_t, rng, noise) for _ in range(n_win)])
    w = np.stack([arc[k : k + n_t] + draw_noise(cov[k], rng) for k in range(n_win)])
    return w, cov


@pytest.mark.parametrize(("lag", "fixed_roots", "noise"), [(3, (1.0,), 0.05), (3, (1.0,), 1.0), (2, (), 0.1)])
def test_identify_windows_equals_the_per_window_stls(lag: int, fixed_roots: tuple[float, ...], noise: float) -> None:
    w, cov = _noisy_windows(40, 15, noise, seed=int(10 * noise) + lag)
    fits = identify_windows(w, lag, cov, fixed_roots=fixed_roots, tol=1e-8)
    for k in range(w.shape[0]):
        ref = stls(w[k], lag, cov=cov[k], structure="shared", fixed_roots=fixed_roots, tol=1e-8,
                   max_starts=1, restarts=False)
        assert fits.status[k] > 0 and ref.success
        assert fits.misfit[k] == pytest.approx(ref.misfit, rel=1e-7)
        np.testing.assert_allclose(fits.r[k], ref.kernel.shared_coefficients(), atol=1e-5)
        np.testing.assert_allclose(fits.w_hat[k], ref.w_hat, atol=1e-6 * np.abs(w[k]).max())
        # identities of the inner problem, independently of the per-window code
        ker = KernelRepresentation.shared(fits.r[k], 3)
        assert np.linalg.norm(ker.residual(fits.w_hat[k])) <= 1e-9 * np.linalg.norm(ker.R) * np.linalg.norm(fits.w_hat[k])
        assert weighted_norm2(w[k] - fits.w_hat[k], cov[k]) == pytest.approx(fits.misfit[k], rel=1e-9)


def test_identify_windows_on_exact_data() -> None:
    arc = circular_arc(40, 0.1)
    w = np.stack([arc[k : k + 12] for k in range(0, 28, 4)])
    fits = identify_windows(w, 3, fixed_roots=(1.0,))
    assert np.all(fits.misfit <= 1e-12 * np.sum(w**2, axis=(1, 2)))
    assert set(fits.status.tolist()) <= {int(StlsStatus.EXACT), int(StlsStatus.CONVERGED)}
    roots = np.roots(fits.r[0][::-1])
    for target in (1.0, np.exp(0.1j), np.exp(-0.1j)):
        assert np.min(np.abs(roots - target)) < 1e-6


@pytest.mark.parametrize("form", ["identity", "diag", "full"])
@pytest.mark.parametrize("kernel", [KernelRepresentation.static(3), KernelRepresentation.pva(3)], ids=["static", "pva"])
def test_project_windows_equals_the_banded_projection(form: str, kernel: KernelRepresentation) -> None:
    w, full = _noisy_windows(6, 11, 0.3, seed=3)
    cov = {"identity": None, "diag": np.einsum("btii->bti", full), "full": full}[form]
    m, w_hat = project_windows(w, kernel.shared_coefficients(), cov)
    for k in range(w.shape[0]):
        ref_m, ref_w = misfit(w[k], kernel, None if cov is None else cov[k])
        assert m[k] == pytest.approx(ref_m, rel=1e-10)
        np.testing.assert_allclose(w_hat[k], ref_w, atol=1e-9 * np.abs(w[k]).max())


def test_per_window_kernels_and_bad_arguments() -> None:
    w, cov = _noisy_windows(3, 8, 0.1, seed=4)
    r = np.array([[-1.0, 1.0], [-0.5, 1.0], [-1.0, 1.0]])
    m, _ = project_windows(w, r, cov)
    assert m[1] == pytest.approx(misfit(w[1], KernelRepresentation.shared(r[1], 3), cov[1])[0], rel=1e-10)
    with pytest.raises(UsageError, match="w"):
        identify_windows(w[0], 3)
    with pytest.raises(UsageError, match="samples"):
        identify_windows(w[:, :4], 3)
    with pytest.raises(UsageError, match="cov"):
        project_windows(w, [-1.0, 1.0], cov[:, :, :2])
    with pytest.raises(UsageError, match="fixed_roots"):
        identify_windows(w, 1, fixed_roots=(1.0, 1.0))
