"""The paper's STLS GDOP (gnss_cli.behavior.paper_gdop) against direct computations."""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.behavior.hankel import hankel
from gnss_cli.behavior.paper_gdop import DegeneratePaperGdopError, paper_stls_gdop, paper_stls_hankel
from gnss_cli.errors import UsageError
from gnss_cli.solvers.problem import Problem
from gnss_cli.solvers.tls import solve_tls_batch


def _direct(h: np.ndarray, n_f: int) -> tuple[float, np.ndarray, np.ndarray]:
    """The reconstructed formula with explicit matrices and inverses."""
    hp, hf = h[:-n_f], h[-n_f:]
    s = np.linalg.svd(h, compute_uv=False)[-1]
    m = hp @ hp.T
    k = np.linalg.inv(m - s**2 * np.eye(m.shape[0]))
    q = k @ m @ k
    return float(np.sqrt(np.trace(q))), q, k @ hp @ hf.T


def _noisy_trajectory(rng: np.random.Generator, n: int, sigma: float) -> np.ndarray:
    """A constant-rate turn (annihilated by a lag-3 shared kernel with a root at 1) plus noise, m."""
    t = np.arange(n)
    w = np.column_stack([300.0 * np.cos(0.05 * t), 300.0 * np.sin(0.05 * t), 50.0 * np.cos(0.05 * t + 1.0)])
    return w + sigma * rng.standard_normal(w.shape)


def test_equals_the_explicit_formula() -> None:
    rng = np.random.default_rng(1)
    for structure in ("shared", "full"):
        h, n_f = paper_stls_hankel(_noisy_trajectory(rng, 15, 1.0), 3, structure)
        g = paper_stls_gdop(h, n_f)
        gdop, q, x = _direct(h, n_f)
        assert g.gdop == pytest.approx(gdop, rel=1e-9)
        np.testing.assert_allclose(g.cov, q, rtol=1e-8, atol=1e-12 * np.abs(q).max())
        np.testing.assert_allclose(g.x, x, rtol=1e-8, atol=1e-10 * np.abs(x).max())


def test_one_epoch_system_is_the_papers_tls_gdop() -> None:
    """H = [A q]^T with one right-hand side: the paper's TLS GDOP, as the TLS solver computes it."""
    rng = np.random.default_rng(2)
    e = rng.standard_normal((8, 3))
    A = np.column_stack([-e / np.linalg.norm(e, axis=1, keepdims=True), np.ones(8)])
    q = A @ np.array([1.0, -2.0, 0.5, 3.0]) + 0.3 * rng.standard_normal(8)
    g = paper_stls_gdop(np.column_stack([A, q]).T, 1)
    res = solve_tls_batch(Problem(A[None], q[None], np.ones((1, 8)), np.ones((1, 8), dtype=bool)))
    assert g.gdop == pytest.approx(float(np.sqrt(np.trace(res.details.cov_paper[0]))), rel=1e-9)
    # and its X is the TLS solution p = -V[:m, m] / V[m, m]
    np.testing.assert_allclose(g.x[:, 0], res.x[0], rtol=1e-8)


def test_exact_data_gives_the_least_squares_gain() -> None:
    """Noise -> 0: s -> 0 and GDOP -> sqrt(trace (H_p H_p^T)^-1) (the paper's GDOP_LS analogue)."""
    w = _noisy_trajectory(np.random.default_rng(3), 20, 0.0)
    h, n_f = paper_stls_hankel(w, 3, "shared")
    g = paper_stls_gdop(h, n_f)
    hp = h[:-1]
    assert g.sigma < 1e-8 * np.linalg.norm(h)
    assert g.gdop == pytest.approx(float(np.sqrt(np.trace(np.linalg.inv(hp @ hp.T)))), rel=1e-6)
    # the exact kernel is found: r~(z) = z^2 - 2 cos(0.05) z + 1 (monic; X^T H_p = H_f)
    np.testing.assert_allclose(g.x[:, 0], [-1.0, 2 * np.cos(0.05)], rtol=1e-7)
    # and a little noise moves it by little, from above (s > 0 enlarges the gain)
    noisy = paper_stls_gdop(*paper_stls_hankel(_noisy_trajectory(np.random.default_rng(3), 20, 1e-3), 3, "shared"))
    assert g.gdop <= noisy.gdop <= 1.01 * g.gdop


def test_cov_is_the_first_order_gain_at_fixed_sigma() -> None:
    """Q = J J^T with J = dX[:, j] / dH_f[j, :] (s held fixed), by central differences."""
    h, n_f = paper_stls_hankel(_noisy_trajectory(np.random.default_rng(4), 15, 1.0), 3, "full")
    g = paper_stls_gdop(h, n_f)
    hp = h[:-n_f]
    k = np.linalg.inv(hp @ hp.T - g.sigma**2 * np.eye(hp.shape[0]))
    step = 1e-3
    j = np.empty((hp.shape[0], h.shape[1]))
    for c in range(h.shape[1]):
        up, dn = h.copy(), h.copy()
        up[-1, c] += step
        dn[-1, c] -= step
        j[:, c] = (k @ hp @ up[-1] - k @ hp @ dn[-1]) / (2 * step)
    np.testing.assert_allclose(j @ j.T, g.cov, rtol=1e-6, atol=1e-9 * np.abs(g.cov).max())


def test_shared_structure_does_not_depend_on_the_origin() -> None:
    w = _noisy_trajectory(np.random.default_rng(5), 15, 1.0)
    a = paper_stls_gdop(*paper_stls_hankel(w, 3, "shared"))
    b = paper_stls_gdop(*paper_stls_hankel(w + [1e4, -3e3, 50.0], 3, "shared"))
    assert a.gdop == pytest.approx(b.gdop, rel=1e-9)


def test_unit_is_inverse_of_the_trajectory_unit() -> None:
    """Scaling w by c (metres -> c units) scales the GDOP by 1/c: it is not a unitless DOP."""
    w = _noisy_trajectory(np.random.default_rng(6), 15, 1.0)
    a = paper_stls_gdop(*paper_stls_hankel(w, 3, "shared"))
    b = paper_stls_gdop(*paper_stls_hankel(1000.0 * w, 3, "shared"))
    assert b.gdop == pytest.approx(a.gdop / 1000.0, rel=1e-9)


def test_full_hankel_is_the_block_hankel_of_w() -> None:
    w = np.arange(30.0).reshape(10, 3)
    h, n_f = paper_stls_hankel(w, 2, "full")
    np.testing.assert_array_equal(h, hankel(w, 3))
    assert n_f == 3


def test_degenerate_cases_raise() -> None:
    # H_f orthogonal to H_p and larger: s_min(H) = s_min(H_p), the TLS nongeneric case; reported, no NaN
    with pytest.raises(DegeneratePaperGdopError, match="nongeneric"):
        paper_stls_gdop(np.vstack([np.eye(10)[0], 2.0 * np.eye(10)[1]]), 1)
    with pytest.raises(DegeneratePaperGdopError, match="zero"):
        paper_stls_gdop(np.zeros((3, 5)), 1)
    with pytest.raises(DegeneratePaperGdopError, match="nothing is identified"):
        paper_stls_hankel(np.zeros((10, 3)), 1, "shared")
    with pytest.raises(UsageError, match="columns"):
        paper_stls_gdop(np.ones((5, 2)), 1)
    with pytest.raises(UsageError, match="n_future"):
        paper_stls_gdop(np.ones((3, 5)), 3)
    with pytest.raises(UsageError, match="finite"):
        paper_stls_gdop(np.full((3, 5), np.nan), 1)
    with pytest.raises(UsageError, match="structure"):
        paper_stls_hankel(np.zeros((10, 3)), 3, "pva")
