"""Multi-epoch geometry in square-root form: ``epoch_information_root`` and ``target_covs``
(DESIGN.md section 5), against the normal-equation forms and dense stacked inverses."""

from __future__ import annotations

import numpy as np

from gnss_cli.behavior import KernelRepresentation
from gnss_cli.behavior.multi_epoch import (
    behavior_basis,
    epoch_information,
    epoch_information_root,
    multi_epoch_cov,
    target_covs,
)


def _rows(rng: np.random.Generator, n_t: int, n_sv: int) -> np.ndarray:
    u = rng.normal(size=(n_t, n_sv, 3))
    return -u / np.linalg.norm(u, axis=2, keepdims=True)


def _two_systems(n_t: int, n_sv: int) -> np.ndarray:
    c = np.zeros((n_t, n_sv, 2))
    c[:, np.arange(n_sv), np.arange(n_sv) % 2] = 1.0
    return c


def test_root_squares_to_the_clock_reduced_information() -> None:
    rng = np.random.default_rng(5)
    n_t, n_sv = 6, 7
    p_m = _rows(rng, n_t, n_sv)
    clocks = _two_systems(n_t, n_sv)
    w = rng.uniform(0.3, 3.0, size=(n_t, n_sv))
    w[1, 1::2] = 0.0  # system 1 absent at epoch 1
    w[2, :5] = 0.0  # two satellites left at epoch 2
    p_nan = p_m.copy()
    p_nan[w == 0] = np.nan  # unused rows may hold anything
    info, h, cv = epoch_information(p_m, w, clocks)
    root, h_r, cv_r = epoch_information_root(p_nan, w, clocks)
    np.testing.assert_allclose(np.swapaxes(root, 1, 2) @ root, info, atol=1e-12)
    np.testing.assert_allclose(h_r, h, atol=1e-14)
    np.testing.assert_allclose(cv_r, cv, atol=1e-14)
    assert cv_r[1, 1] == 0.0 and np.all(np.tril(root, -1) == 0.0)
    # fewer rows than columns: the factor is still (3, 3)
    root2, _, _ = epoch_information_root(p_m[:, :2], np.ones((n_t, 2)))
    info2, _, _ = epoch_information(p_m[:, :2], np.ones((n_t, 2)))
    assert root2.shape == (n_t, 3, 3)
    np.testing.assert_allclose(np.swapaxes(root2, 1, 2) @ root2, info2, atol=1e-12)


def test_target_covs_equal_multi_epoch_cov_and_do_not_depend_on_the_chunk() -> None:
    rng = np.random.default_rng(6)
    n_t, n_sv, n_win = 20, 8, 6
    p_m = _rows(rng, n_t, n_sv)
    w = np.ones((n_t, n_sv))
    clocks = _two_systems(n_t, n_sv)
    root, h, cv = epoch_information_root(p_m, w, clocks)
    info, h_i, cv_i = epoch_information(p_m, w, clocks)
    kernels = [KernelRepresentation.pva(3), KernelRepresentation.shared(np.poly([1.0, 0.9, 0.8])[::-1], 3)]
    bases = np.stack([behavior_basis(k, n_win) for k in kernels[:1]])
    bases2 = behavior_basis(kernels[1], n_win)
    starts = np.arange(n_t - n_win + 1)
    spans = starts[:, None] + np.arange(n_win)
    # every window with the pva basis; targets: every epoch of every window
    window_of = np.repeat(np.arange(starts.size), n_win)
    position = np.tile(np.arange(n_win), starts.size)
    got = target_covs(root, h, cv, spans, bases, np.zeros(starts.size, dtype=np.intp), window_of, position)
    small = target_covs(root, h, cv, spans, bases, np.zeros(starts.size, dtype=np.intp), window_of, position, chunk=2)
    ref = multi_epoch_cov(bases[0][None].repeat(starts.size, 0), info[spans], h_i[spans], cv_i[spans])
    np.testing.assert_allclose(got.cov, ref.reshape(-1, 5, 5), rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(got.cov, small.cov)
    assert got.determined.all() and got.full_rank.all() and np.all(np.isfinite(got.cond)) and np.all(got.cond >= 1)
    # two bases, windows pointing at either
    both = np.stack([bases[0], bases2])
    which = starts % 2
    mixed = target_covs(root, h, cv, spans, both, which, window_of, position)
    ref2 = multi_epoch_cov(both[which], info[spans], h_i[spans], cv_i[spans])
    np.testing.assert_allclose(mixed.cov, ref2.reshape(-1, 5, 5), rtol=1e-9, atol=1e-12)


def test_condition_number_is_the_frobenius_one_of_the_stacked_rows() -> None:
    rng = np.random.default_rng(8)
    p_m = _rows(rng, 5, 6)
    root, h, cv = epoch_information_root(p_m, np.ones((5, 6)))
    basis = behavior_basis(KernelRepresentation.shared([1.0, -2.0, 1.0], 3), 5)
    res = target_covs(root, h, cv, np.arange(5)[None], basis[None], np.zeros(1, dtype=np.intp),
                      np.array([0]), np.array([2]))
    s = np.linalg.svd(np.concatenate([root[t] @ basis[t] for t in range(5)]), compute_uv=False)
    assert np.isclose(res.cond[0], np.linalg.norm(s) * np.linalg.norm(1.0 / s), rtol=1e-10)


def test_rank_deficient_window_determines_only_epochs_off_its_null_space() -> None:
    """cv over 5 epochs; every epoch but the middle one sees the same 3 satellites (one clock):
    the trajectory ``(t - 2) d`` with ``d`` their unobserved direction is invisible, so only the
    middle epoch is determined; its block equals the dense pseudo-inverse one."""
    rng = np.random.default_rng(9)
    n_t = 5
    three = _rows(rng, 1, 3)[0]
    p_m = np.zeros((n_t, 6, 3))
    w = np.zeros((n_t, 6))
    p_m[:, :3], w[:, :3] = three, 1.0
    p_m[2] = _rows(rng, 1, 6)[0]
    w[2] = 1.0
    root, h, cv = epoch_information_root(p_m, w)
    basis = behavior_basis(KernelRepresentation.shared([1.0, -2.0, 1.0], 3), n_t)
    res = target_covs(root, h, cv, np.arange(n_t)[None], basis[None], np.zeros(1, dtype=np.intp),
                      np.zeros(n_t, dtype=np.intp), np.arange(n_t))
    assert not res.full_rank.any() and np.all(np.isinf(res.cond))
    assert res.determined.tolist() == [False, False, True, False, False]
    assert np.all(np.isnan(res.cov[[0, 1, 3, 4]])) and np.all(np.isfinite(res.cov[2]))
    d = basis.shape[2]
    g = np.zeros((n_t * 6, d + n_t))
    for t in range(n_t):
        g[t * 6:(t + 1) * 6, :d] = (p_m[t] @ basis[t]) * w[t][:, None]
        g[t * 6:(t + 1) * 6, d + t] = w[t]
    q = np.linalg.pinv(g.T @ g)
    jac = np.zeros((4, d + n_t))
    jac[:3, :d] = basis[2]
    jac[3, d + 2] = 1.0
    np.testing.assert_allclose(res.cov[2], jac @ q @ jac.T, rtol=1e-8, atol=1e-10)


def _recursion_matrix(r: np.ndarray, n_t: int) -> np.ndarray:
    """The recursion ``sum_k r_k w(t+k) = 0`` as an ``(n_t - l) x n_t`` Toeplitz matrix (scipy's): its
    null space is the behavior."""
    from scipy.linalg import toeplitz

    lag = r.size - 1
    first_row = np.concatenate([r, np.zeros(n_t - lag - 1)])
    return toeplitz(np.r_[r[0], np.zeros(n_t - lag - 1)], first_row)


def test_behavior_bases_keep_every_mode_over_long_windows() -> None:
    """Identified kernels can have a root far from the unit circle; over a whole segment (up to
    1,800 epochs) its free response grows past float range, or swamps the other modes below the
    rank threshold, forwards and backwards alike. The basis must still have all ``q l`` columns,
    orthonormal and annihilated by the kernel, and span the null space of the recursion's matrix
    (scipy's SVD, independent) -- a 24 h simulated flight stopped here once."""
    from scipy.linalg import null_space

    for roots in ([3.0, 1e-3, 1.0], [-2.5, 0.3, 1.0], [0.5, 1.6, 1.0], [1.0, 1.0, 1.0], [0.0, 1.0, 1.0]):
        r = np.real(np.poly(roots))[::-1]
        ker = KernelRepresentation.shared(r, 3)
        for n_t in (15, 300, 1800):
            basis = behavior_basis(ker, n_t)
            assert basis.shape == (n_t, 3, 9), (roots, n_t, basis.shape)
            flat = basis.reshape(n_t * 3, 9)
            np.testing.assert_allclose(flat.T @ flat, np.eye(9), atol=1e-12)
            for col in range(9):
                w = basis[:, :, col]
                assert np.linalg.norm(ker.residual(w)) <= 1e-9 * np.linalg.norm(r), (roots, n_t, col)
            if n_t == 300:
                scalar = basis[:, 0, 0::3]  # r(z) I_3: the x responses are the scalar behavior
                ref = null_space(_recursion_matrix(r, n_t))
                np.testing.assert_allclose(scalar @ scalar.T, ref @ ref.T, atol=1e-10)


def test_general_kernel_basis_keeps_every_mode_over_long_windows() -> None:
    """The same for a kernel that is not shared (each axis its own roots): the one-pass recursion
    overflows on the axis with a root at 2.5; the swept responses span all ``q l`` modes."""
    rx = np.real(np.poly([2.5, 1.0, 1.0]))[::-1]
    ry = np.real(np.poly([0.2, 1.0, 1.0]))[::-1]
    rz = np.real(np.poly([1.0, 1.0, 1.0]))[::-1]
    blocks = np.zeros((4, 3, 3))
    for axis, r in enumerate((rx, ry, rz)):
        blocks[:, axis, axis] = r
    ker = KernelRepresentation(np.concatenate(list(blocks), axis=1))
    assert not ker.is_shared()
    for n_t in (20, 1200):
        basis = behavior_basis(ker, n_t)
        assert basis.shape == (n_t, 3, 9)
        flat = basis.reshape(n_t * 3, 9)
        np.testing.assert_allclose(flat.T @ flat, np.eye(9), atol=1e-12)
        for col in range(9):
            assert np.linalg.norm(ker.residual(basis[:, :, col])) <= 1e-9 * np.linalg.norm(ker.R)
