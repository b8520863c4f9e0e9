"""A window's batched STLS fit does not depend on the other windows of its batch, to the bit.

A window's batch depends on the length of the segment it is cut from (a piece of a long file
holds fewer windows than the whole file), and the descent shrinks its batch to the windows
still active, down to one. numpy sums in another order over an axis of length one (einsum)
and BLAS rounds a row of a matrix product differently with the number of rows, so the
batched code avoids both (:func:`gnss_cli.behavior.batch_projection.einsum_windows`).

To the bit with numpy 2. numpy 1.x's vectorized sums change their last bits with the arrays'
memory alignment from one run to the next (seen with numpy 1.25, the lowest version allowed), so
there a window alone and in its batch are held to 1e-9 relative instead.
"""

from __future__ import annotations

import numpy as np

from gnss_cli.behavior.batch import identify_windows, project_windows

NUMPY_2 = int(np.__version__.split(".")[0]) >= 2


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal bits with numpy 2; equal to 1e-9 relative with numpy 1.x (module docstring)."""
    return bool(np.array_equal(a, b)) if NUMPY_2 else bool(np.allclose(a, b, rtol=1e-9, atol=1e-12))


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
              if not _same(identify_windows(w[k:k + 1], 3, cov[k:k + 1], fixed_roots=(1.0,)).r[0], full.r[k])]
    assert differ == []
    half = identify_windows(w[::2], 3, cov[::2], fixed_roots=(1.0,))
    assert _same(half.w_hat, full.w_hat[::2]) and _same(half.misfit, full.misfit[::2])


def test_projected_window_alone_equals_the_window_in_a_batch() -> None:
    w, cov = _windows(n_b=40)
    mis, w_hat = project_windows(w, [-1.0, 3.0, -3.0, 1.0], cov)
    for k in range(0, 40, 7):
        m1, w1 = project_windows(w[k:k + 1], [-1.0, 3.0, -3.0, 1.0], cov[k:k + 1])
        assert _same(m1[0], mis[k]) and _same(w1[0], w_hat[k])
