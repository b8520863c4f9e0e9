"""Shared-kernel STLS and fixed-kernel projections for many short windows at once.

Sliding-window smoothing (:mod:`gnss_cli.pipeline.behavioral`) solves thousands of small, independent
problems of the same size (e.g. 15 epochs of ``q = 3`` coordinates). Each one is cheap; what
costs is the overhead of the many small array operations of the per-window path. Here every
array carries a leading window axis ``B`` and one pass of the algorithm serves all windows:

* :func:`project_windows` -- the projection onto a fixed shared kernel ``r(z) I_q`` (static,
  PVA) for every window;
* :func:`identify_windows` -- the weighted Hankel STLS of :func:`gnss_cli.behavior.stls` with
  ``structure="shared"``, ``max_starts=1, restarts=False``: the same starting kernels (WTLS and
  the polynomial ``(z-1)^m``, the one with the lower misfit), the same chart (``r~`` with its
  largest coefficient pinned to one, re-charted when a coordinate exceeds the threshold), the
  same damped Newton steps with the exact Hessian (Gauss--Newton where it is indefinite) and
  the same acceptance and stopping rules, evaluated window by window in lockstep.

The band of ``Gamma = G Sigma G^T`` (``n = N - l`` block rows) is built for every window at
once and factored window by window by LAPACK's banded Cholesky (the factor of
:mod:`gnss_cli.behavior.banded`), whose cost grows with ``n`` only linearly: the same code serves
15-epoch windows and whole segments of hundreds of epochs. Windows are processed in chunks of
:data:`CHUNK` to bound the memory. The batched projection is in
:mod:`gnss_cli.behavior.batch_projection`, the lockstep descent in
:mod:`gnss_cli.behavior.batch_descent`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnss_cli.behavior.batch_descent import identify_chunk
from gnss_cli.behavior.batch_projection import F64, Windows, project_batch
from gnss_cli.behavior.descent import MU_INITIAL, MU_REJECTED
from gnss_cli.behavior.kernel import shared_kernel_coefficients
from gnss_cli.behavior.result import StlsStatus
from gnss_cli.errors import UsageError

__all__ = ["WindowFits", "identify_windows", "project_windows", "CHUNK"]

#: Windows per batch (bounds the memory: a few ``(CHUNK, n q, q (l + 1))`` arrays).
CHUNK = 1024


@dataclass(frozen=True, slots=True)
class WindowFits:
    """Shared kernels and corrected trajectories of ``B`` windows.

    Attributes
    ----------
    r : ndarray, shape (B, l+1)
        Ascending coefficients of ``r(z)`` (monic when ``r_l`` is not negligible, as the
        kernel of :func:`gnss_cli.behavior.stls`); NaN for infeasible windows.
    w_hat : ndarray, shape (B, N, q)
        Closest trajectories of the identified behaviors (the data for infeasible windows).
    misfit : ndarray, shape (B,)
        Weighted misfits (``inf`` for infeasible windows).
    status : ndarray of int, shape (B,)
        :class:`~gnss_cli.behavior.result.StlsStatus` values.
    iterations, n_evaluations : ndarray of int, shape (B,)
        Outer iterations and inner problems solved per window.
    """

    r: F64
    w_hat: F64
    misfit: F64
    status: NDArray[np.int64]
    iterations: NDArray[np.int64]
    n_evaluations: NDArray[np.int64]


def _full_cov(cov: ArrayLike | None, shape: tuple[int, int, int]) -> F64:
    """Covariances as ``(B, N, q, q)`` (from None, ``(B, N, q)`` variances or matrices)."""
    n_b, n_t, q = shape
    if cov is None:
        return np.broadcast_to(np.eye(q), (n_b, n_t, q, q))
    arr = np.asarray(cov, dtype=np.float64)
    if arr.shape == (n_b, n_t, q):
        return arr[..., None] * np.eye(q)
    if arr.shape == (n_b, n_t, q, q):
        return arr
    raise UsageError(f"cov: expected None, shape {(n_b, n_t, q)} or {(n_b, n_t, q, q)}, received {arr.shape}")


def _validate(w: ArrayLike, cov: ArrayLike | None, lag: int) -> tuple[F64, F64]:
    arr = np.asarray(w, dtype=np.float64)
    if arr.ndim != 3 or min(arr.shape) == 0:
        raise UsageError(f"w: expected windows of shape (B, N, q), received shape {arr.shape}")
    if isinstance(lag, bool) or not isinstance(lag, (int, np.integer)) or lag < 1:
        raise UsageError(f"lag: expected an integer >= 1, received {lag!r}")
    if arr.shape[1] < lag + 2:
        raise UsageError(f"w: expected at least lag + 2 = {lag + 2} samples per window, received {arr.shape[1]}")
    if not np.all(np.isfinite(arr)):
        raise UsageError("w: expected finite values")
    sig = _full_cov(cov, arr.shape)
    if not np.all(np.isfinite(sig)):
        raise UsageError("cov: expected finite covariances")
    return arr, sig


def project_windows(w: ArrayLike, r: ArrayLike, cov: ArrayLike | None = None) -> tuple[F64, F64]:
    """Project every window onto the trajectories of a fixed shared kernel ``r(z) I_q``.

    Parameters
    ----------
    w : array_like, shape (B, N, q)
        Windows (e.g. ENU positions, m).
    r : array_like, shape (l+1,) or (B, l+1)
        Ascending coefficients of ``r(z)``, one for all windows or one per window.
    cov : array_like, optional
        Covariances ``(B, N, q, q)``, variances ``(B, N, q)`` or None (identity).

    Returns
    -------
    misfit : ndarray, shape (B,)
        ``min sum_t (w_t - w^_t)^T Sigma_t^{-1} (w_t - w^_t)`` per window (``inf`` where
        ``G Sigma G^T`` is singular).
    w_hat : ndarray, shape (B, N, q)
        The projections (the data where singular).

    Raises
    ------
    UsageError
        Invalid shapes or values.

    Examples
    --------
    >>> import numpy as np
    >>> w = np.array([[[0.0], [1.0], [0.0], [1.0]]])
    >>> m, w_hat = project_windows(w, [-1.0, 1.0])
    >>> round(float(m[0]), 12), w_hat[0, :, 0].round(12).tolist()
    (1.0, [0.5, 0.5, 0.5, 0.5])
    """
    coef = np.asarray(r, dtype=np.float64)
    lag = coef.shape[-1] - 1 if coef.ndim in (1, 2) else 0
    arr, sig = _validate(w, cov, lag)
    coef = np.broadcast_to(coef, (arr.shape[0], lag + 1)) if coef.ndim == 1 else coef
    if coef.shape != (arr.shape[0], lag + 1) or not np.all(np.isfinite(coef)):
        raise UsageError(f"r: expected finite coefficients of shape ({lag + 1},) or ({arr.shape[0]}, {lag + 1})")
    misfit = np.empty(arr.shape[0])
    w_hat = np.empty_like(arr)
    for lo in range(0, arr.shape[0], CHUNK):
        sel = np.arange(lo, min(lo + CHUNK, arr.shape[0]))
        proj = project_batch(Windows(arr[sel], sig[sel], lag), coef[sel])
        misfit[sel] = proj.misfit
        w_hat[sel] = np.where(proj.ok[:, None, None], proj.w_hat, arr[sel])
    return misfit, w_hat


def identify_windows(
    w: ArrayLike,
    lag: int,
    cov: ArrayLike | None = None,
    *,
    fixed_roots: Sequence[complex] = (),
    tol: float = 1e-10,
    max_iter: int = 200,
    rechart_threshold: float = 10.0,
) -> WindowFits:
    """Identify a shared kernel ``r(z) I_q`` of lag ``lag`` in every window (batched STLS).

    Parameters
    ----------
    w : array_like, shape (B, N, q)
        Windows of uniformly sampled series (e.g. ENU positions, m), ``N >= lag + 2``.
    lag : int
        Lag ``l >= 1``.
    cov : array_like, optional
        Covariances ``(B, N, q, q)``, variances ``(B, N, q)`` or None (identity).
    fixed_roots : sequence of complex
        Roots kept in every ``r(z)`` (e.g. ``(1.0,)``).
    tol, max_iter, rechart_threshold : float, int, float
        As in :func:`gnss_cli.behavior.stls`.

    Returns
    -------
    WindowFits

    Raises
    ------
    UsageError
        Invalid arguments.

    Notes
    -----
    Window ``k`` of the result equals ``stls(w[k], lag, cov=cov[k], structure="shared",
    fixed_roots=fixed_roots, tol=tol, max_iter=max_iter, max_starts=1, restarts=False)`` up
    to rounding (the lockstep descent sums in another order), which the tests check.
    """
    arr, sig = _validate(w, cov, lag)
    if not (isinstance(tol, (float, int)) and 0.0 < tol < 1.0):
        raise UsageError(f"tol: expected a number in (0, 1), received {tol!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 0:
        raise UsageError(f"max_iter: expected a non-negative integer, received {max_iter!r}")
    fixed = shared_kernel_coefficients(fixed_roots)
    deg = int(lag) - (fixed.size - 1)
    if deg < 0:
        raise UsageError(f"fixed_roots: expected at most lag = {lag} roots, received {fixed.size - 1}")
    n_b = arr.shape[0]
    out_r = np.full((n_b, lag + 1), np.nan)
    out_w = arr.copy()
    out_m = np.full(n_b, np.inf)
    out_s = np.full(n_b, int(StlsStatus.INFEASIBLE), dtype=np.int64)
    out_i = np.zeros(n_b, dtype=np.int64)
    out_e = np.zeros(n_b, dtype=np.int64)
    consts = (MU_INITIAL, MU_REJECTED)
    for lo in range(0, n_b, CHUNK):
        sel = np.arange(lo, min(lo + CHUNK, n_b))
        res = identify_chunk(Windows(arr[sel], sig[sel], int(lag)), fixed, deg, float(tol), int(max_iter),
                              float(rechart_threshold), consts)
        out_r[sel], out_w[sel], out_m[sel], out_s[sel], out_i[sel], out_e[sel] = res
    return WindowFits(out_r, out_w, out_m, out_s, out_i, out_e)


