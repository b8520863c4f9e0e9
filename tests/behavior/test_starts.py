"""Starting kernels of the STLS: subspace, modal re-fit, mirrored poles, coarse-to-fine."""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.behavior import EpochCovariance, KernelRepresentation, misfit, stls, wtls
from gnss_cli.behavior.starts import modal_kernel, subspace_kernel

from behavior_trajectories import circular_arc, nine_mode_series


def _identity(n_t: int) -> EpochCovariance:
    return EpochCovariance.from_arg(None, n_t, 3)


@pytest.mark.parametrize("depth", [4, 8, 12])
def test_subspace_kernel_annihilates_exact_data(depth: int) -> None:
    w = nine_mode_series(60, np.random.default_rng(1))
    r = subspace_kernel(w, 3, 3, _identity(60), depth)
    assert r is not None
    assert KernelRepresentation(r, q=3).annihilates(w, rtol=1e-8)


def test_subspace_kernel_of_depth_l_plus_1_is_the_wtls_kernel() -> None:
    rng = np.random.default_rng(2)
    w = nine_mode_series(50, rng) + 0.01 * rng.normal(size=(50, 3))
    r = subspace_kernel(w, 3, 3, _identity(50), 4)
    r_wtls = np.array(wtls(w, lag=3).kernel.R)
    # the same row space: projecting one onto the other changes nothing
    proj = r_wtls.T @ np.linalg.pinv(r_wtls.T)
    np.testing.assert_allclose(proj @ r.T, r.T, atol=1e-8)


def test_subspace_kernel_refuses_depths_the_data_cannot_fill() -> None:
    w = np.random.default_rng(3).normal(size=(12, 3))
    assert subspace_kernel(w, 3, 3, _identity(12), 8) is None  # T - depth + 1 = 5 <= order 9
    assert subspace_kernel(w, 3, 3, _identity(12), 3) is None  # shallower than l + 1


def test_modal_kernel_of_the_true_poles_recovers_the_behavior() -> None:
    rng = np.random.default_rng(4)
    w = nine_mode_series(60, rng)
    k_true = stls(w, lag=3).kernel
    # a kernel with the same poles but scrambled output directions
    scrambled = KernelRepresentation(np.array(k_true.R) @ np.kron(np.eye(4), np.linalg.qr(rng.normal(size=(3, 3)))[0]), q=3)
    assert not scrambled.annihilates(w, rtol=1e-6)
    r = modal_kernel(w, scrambled, _identity(60))
    assert r is not None and KernelRepresentation(r, q=3).annihilates(w, rtol=1e-7)


def test_mirrored_reflects_only_the_unstable_poles() -> None:
    poles = np.array([1.25, 0.5 + 0.6j, 0.5 - 0.6j])
    shared = KernelRepresentation.shared(np.real(np.poly(poles))[::-1], 3)
    mirrored = shared.mirrored()
    assert mirrored is not None and mirrored.is_shared()
    np.testing.assert_allclose(np.sort_complex(np.roots(mirrored.shared_coefficients()[::-1])),
                               np.sort_complex(np.array([0.8, 0.5 + 0.6j, 0.5 - 0.6j])), atol=1e-12)
    assert KernelRepresentation.pva(3).mirrored() is None  # all poles on the unit circle
    # a general kernel: one real pole outside among nine
    w = nine_mode_series(40, np.random.default_rng(5))
    k = stls(w, lag=3).kernel
    comp_poles = k.poles()
    assert k.mirrored() is None and np.all(np.abs(comp_poles) < 1)
    a = k.transition()
    n = 9
    comp = np.zeros((n, n))
    comp[:6, 3:] = np.eye(6)
    comp[6:] = a
    ev, vec = np.linalg.eig(comp)
    j = int(np.argmin(np.abs(ev - 0.9)))  # the real mode 0.9^t
    ev_out = ev.copy()
    ev_out[j] = 1 / 0.9
    a_out = np.real(vec @ np.diag(ev_out) @ np.linalg.inv(vec))
    obs = np.vstack([np.eye(3, n) @ np.linalg.matrix_power(a_out, i) for i in range(4)])
    unstable = KernelRepresentation(np.linalg.svd(obs)[0][:, n:].T, q=3)
    back = unstable.mirrored()
    assert back is not None
    distance = np.abs(back.poles()[:, None] - comp_poles[None, :])
    assert np.all(distance.min(axis=1) < 1e-8) and np.all(distance.min(axis=0) < 1e-8)


def test_coarse_start_reaches_the_same_optimum_as_a_direct_descent() -> None:
    rng = np.random.default_rng(6)
    n_t = 6000
    y = circular_arc(n_t, 2 * np.pi / 150, radius_m=1.0) + 0.05 * rng.normal(size=(n_t, 3))
    res = stls(y, lag=1, order=3)  # T >= 4000: starts from the kernel of the leading T / 4 samples
    direct = stls(y, lag=1, order=3, kernel0=wtls(y, lag=1, order=3).kernel)
    assert res.success and direct.success
    assert res.misfit == pytest.approx(direct.misfit, rel=1e-9)
    assert misfit(y, res.kernel)[0] == pytest.approx(res.misfit, rel=1e-9)
