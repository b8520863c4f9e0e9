"""A window's batched STLS fit does not depend on the other windows of its batch, to the bit.

A window's batch depends on the length of the segment it is cut from (a piece of a long file
holds fewer windows than the whole file), and the descent shrinks its batch to the windows
still active, down to one. numpy sums in another order over an axis of length one (einsum)
and BLAS rounds a row of a matrix product differently with the number of rows, so the
batched code avoids both (:func:`gnss_cli.behavior.batch_projection.einsum_windows`).
"""

from __future__ import annotations

import numpy as np

from gnss_cli.behavior.batch import identify_windows, project_windows


def _windows(n_b: int = 120, n_t: int = 15, seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """ENU-like windows (m): a slow drift plus noise, with a different covariance at every epoch."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_t)[None, :, None]
    w = rng.normal(0.0, 0.3, (n_b, 1, 3)) * t + rng.normal(0.0, 1.0, (n_b, n_t, 3))
    a = rng.normal(0.0, 1.0, (n_b, n_t, 3, 3))
    cov = np.einsum("btij,btkj->btik", a, a) + 0.5 * np.eye(3)
    return w, cov


def test_identified_window_alone_equals_the_window_in_a_batch() -> None:
    w, cov = _windows()
    full = identify_windows(w, 3, cov, fixed_roots=(1.0,))
    differ = [k for k in range(w.shape[0])
              if not np.array_equal(identify_windows(w[k:k + 1], 3, cov[k:k + 1], fixed_roots=(1.0,)).r[0], full.r[k])]
    assert differ == []
    half = identify_windows(w[::2], 3, cov[::2], fixed_roots=(1.0,))
    assert np.array_equal(half.w_hat, full.w_hat[::2]) and np.array_equal(half.misfit, full.misfit[::2])


def test_projected_window_alone_equals_the_window_in_a_batch() -> None:
    w, cov = _windows(n_b=40)
    mis, w_hat = project_windows(w, [-1.0, 3.0, -3.0, 1.0], cov)
    for k in range(0, 40, 7):
        m1, w1 = project_windows(w[k:k + 1], [-1.0, 3.0, -3.0, 1.0], cov[k:k + 1])
        assert m1[0] == mis[k] and np.array_equal(w1[0], w_hat[k])
