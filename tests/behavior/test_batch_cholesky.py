"""The batched banded Cholesky factors of the window projections."""

from __future__ import annotations

import warnings

import numpy as np

from gnss_cli.behavior.batch_projection import _cholesky


def _banded_spd(rng: np.random.Generator, m: int, kd: int) -> np.ndarray:
    a = rng.normal(size=(m, m))
    a = a @ a.T + m * np.eye(m)
    band = np.abs(np.subtract.outer(np.arange(m), np.arange(m))) <= kd
    return np.where(band, a, 0.0) + 3 * m * np.eye(m)


def test_factors_equal_numpy_and_an_overflowed_window_is_flagged_quietly():
    """A window whose entries overflowed (a kernel with huge coefficients: seen with ``--lag 4``)
    is replaced by the identity without a RuntimeWarning on the user's terminal."""
    rng = np.random.default_rng(3)
    m, kd = 9, 3
    good = np.stack([_banded_spd(rng, m, kd) for _ in range(3)])
    overflowed = _banded_spd(rng, m, kd)
    overflowed[4, 2] = overflowed[2, 4] = np.inf
    gam = np.concatenate([good, overflowed[None]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        chol, ok = _cholesky(gam, kd)
    assert ok.tolist() == [True, True, True, False]
    for b in range(3):
        np.testing.assert_allclose(chol[b], np.linalg.cholesky(good[b]), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(chol[3], np.eye(m))
