"""Clock-reduced epoch normals against dense least squares."""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.behavior.window_solve import free_misfit, reduce_epochs


def _epochs(rng: np.random.Generator, n_t: int, n: int, k: int, n_sats: list[int]) -> tuple[np.ndarray, ...]:
    """Random unit line-of-sight rows, weights (0 beyond each epoch's satellite count), values, clock columns."""
    e = rng.normal(size=(n_t, n, 3))
    e /= np.linalg.norm(e, axis=-1, keepdims=True)
    w = rng.uniform(0.5, 2.0, size=(n_t, n)) * (np.arange(n)[None, :] < np.array(n_sats)[:, None])
    y = rng.normal(size=(n_t, n))
    sys_of = np.arange(n) % k
    c = np.broadcast_to((sys_of[:, None] == np.arange(k)).astype(float), (n_t, n, k)).copy()
    return -e, w, y, c


def _dense_clock_misfit(p: np.ndarray, w: np.ndarray, y: np.ndarray, c: np.ndarray, z: np.ndarray) -> float:
    """min over the clocks of one epoch's weighted misfit at position correction z (dense lstsq)."""
    used = w > 0
    sw = np.sqrt(w[used])
    cols = c[used][:, c[used].any(axis=0)]
    resid = y[used] - p[used] @ z
    if cols.shape[1] == 0:
        return float(np.sum(w[used] * resid**2))
    b, *_ = np.linalg.lstsq(cols * sw[:, None], resid * sw, rcond=None)
    return float(np.sum(w[used] * (resid - cols @ b) ** 2))


def test_reduced_normals_give_the_clock_minimized_misfit() -> None:
    rng = np.random.default_rng(1)
    p, w, y, c = _epochs(rng, 5, 9, 2, [9, 6, 3, 2, 1])
    nrm = reduce_epochs(p, w, y, c)
    for t in range(5):
        z = rng.normal(size=3)
        quad = nrm.s[t] - 2 * z @ nrm.r[t] + z @ nrm.M[t] @ z
        assert quad == pytest.approx(_dense_clock_misfit(p[t], w[t], y[t], c[t], z), rel=1e-10, abs=1e-10)
    # one satellite: its clock takes the row, the position learns nothing
    assert np.allclose(nrm.M[4], 0.0) and nrm.s[4] == pytest.approx(0.0, abs=1e-12)
    assert nrm.n_rows.tolist() == [9, 6, 3, 2, 1] and nrm.n_free.tolist() == [2, 2, 2, 2, 1]


def test_free_misfit_is_each_epoch_solved_alone() -> None:
    rng = np.random.default_rng(2)
    p, w, y, c = _epochs(rng, 4, 8, 1, [8, 5, 4, 2])
    nrm = reduce_epochs(p, w, y, c)
    mis, rank = free_misfit(nrm)
    for t in range(4):
        used = w[t] > 0
        a = np.hstack([p[t][used], c[t][used]]) * np.sqrt(w[t][used])[:, None]
        sol, *_ = np.linalg.lstsq(a, y[t][used] * np.sqrt(w[t][used]), rcond=None)
        assert mis[t] == pytest.approx(float(np.sum((y[t][used] * np.sqrt(w[t][used]) - a @ sol) ** 2)), abs=1e-9)
    assert rank.tolist() == [3, 3, 3, 1]
