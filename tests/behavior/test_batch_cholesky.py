"""The banded Cholesky factors of the window projections."""

from __future__ import annotations

import warnings

import numpy as np

from gnss_cli.behavior.batch_projection import _cholesky, solve_lower_batch


def _banded_spd(rng: np.random.Generator, m: int, kd: int) -> np.ndarray:
    a = rng.normal(size=(m, m))
    a = a @ a.T + m * np.eye(m)
    band = np.abs(np.subtract.outer(np.arange(m), np.arange(m))) <= kd
    return np.where(band, a, 0.0) + 3 * m * np.eye(m)


def _band(gam: np.ndarray, kd: int) -> np.ndarray:
    """``ab_t[j, i - j] = gam[i, j]`` for ``0 <= i - j <= kd`` (zero past the last row)."""
    m = gam.shape[0]
    out = np.zeros((m, kd + 1))
    for j in range(m):
        col = gam[j : min(m, j + kd + 1), j]
        out[j, : col.size] = col
    return out


def _dense(ab_t: np.ndarray) -> np.ndarray:
    m, width = ab_t.shape
    out = np.zeros((m, m))
    for j in range(m):
        n = min(width, m - j)
        out[j : j + n, j] = ab_t[j, :n]
    return out


def test_factors_and_solves_equal_numpy_and_an_overflowed_window_is_flagged_quietly():
    """Each window's factor is numpy's dense Cholesky factor, and the batched triangular solves
    are numpy's; a window whose entries overflowed (a kernel with huge coefficients: seen with
    ``--lag 4``) is replaced by the identity without a RuntimeWarning on the user's terminal."""
    rng = np.random.default_rng(3)
    m, kd = 9, 3
    good = np.stack([_banded_spd(rng, m, kd) for _ in range(3)])
    overflowed = _banded_spd(rng, m, kd)
    overflowed[4, 2] = overflowed[2, 4] = np.inf
    gam = np.concatenate([good, overflowed[None]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        chol, ok = _cholesky(np.stack([_band(g, kd) for g in gam]))
    assert ok.tolist() == [True, True, True, False]
    rhs = rng.normal(size=(4, m, 2))
    x, xt = solve_lower_batch(chol, rhs), solve_lower_batch(chol, rhs, transpose=True)
    for b in range(3):
        lower = np.linalg.cholesky(good[b])
        np.testing.assert_allclose(_dense(chol[b]), lower, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(x[b], np.linalg.solve(lower, rhs[b]), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(xt[b], np.linalg.solve(lower.T, rhs[b]), rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(_dense(chol[3]), np.eye(m))


def test_a_singular_window_is_flagged_and_the_others_are_not():
    """A window whose matrix is rank-deficient fails the pivot test; its neighbours are unaffected."""
    rng = np.random.default_rng(4)
    m, kd = 8, 2
    good = _banded_spd(rng, m, kd)
    v = np.zeros(m)
    v[:3] = 1.0
    singular = np.outer(v, v)  # rank one, inside the band
    chol, ok = _cholesky(np.stack([_band(good, kd), _band(singular, kd), _band(good, kd)]))
    assert ok.tolist() == [True, False, True]
    np.testing.assert_array_equal(chol[0], chol[2])
