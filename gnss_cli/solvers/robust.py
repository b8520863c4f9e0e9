"""M-estimators (Huber, Cauchy) by iteratively reweighted least squares, stacked over epochs.

Nothing here knows GNSS: the functions see design matrices, right-hand sides, row sigmas and
masks, with the epoch axis first.

Notes
-----
For every epoch (rows ``i`` used, ``a_i`` the rows of ``A``, ``sigma_i`` the a-priori sigma of
row ``i``) the estimate minimizes

``sum_i s_i rho(u_i)``,   ``u_i = (q_i - a_i^T x) / sigma_i``  (standardized residual),

with ``s_i = 1`` (weighted: the a-priori weights ``1 / sigma_i^2`` enter through ``u_i``) or
``s_i = sigma_i^2`` (unweighted: equal a-priori weights; ``u_i`` still decides which rows are
outliers). The estimating equations are

``sum_i s_i psi(u_i) a_i / sigma_i = 0``  <=>  ``A^T W_e (q - A x) = 0``,
``W_e = diag(b_i w(u_i))``,  ``w(u) = psi(u) / u``,  ``b_i = 1 / sigma_i^2`` (or 1 unweighted),

which IRLS solves as a fixed point: ``w <- w(u(x))``, ``x <- argmin sum_i b_i w_i (q_i -
a_i^T x)^2`` (a weighted least-squares solve on the whitened rows, QR), until no weight changes
by more than ``tolerance`` between two iterations, or ``max_iterations``. ``w(u)`` does not
increase with ``|u|``, so the weighted quadratic majorizes ``rho`` at the current residuals and
no step increases the objective (Huber 1981, section 7.8).

=========  ======================================  ===========================  ===============
estimator  ``rho(u)``                              ``psi(u)``                   ``w(u)``
=========  ======================================  ===========================  ===============
huber      ``u^2/2`` for ``|u| <= k``, else        ``clip(u, -k, k)``           ``min(1, k/|u|)``
           ``k |u| - k^2/2``
cauchy     ``(c^2/2) ln(1 + (u/c)^2)``             ``u / (1 + (u/c)^2)``        ``1/(1+(u/c)^2)``
=========  ======================================  ===========================  ===============

The usual tuning constants give 95 % efficiency at the normal distribution: Huber
``k = 1.345``, Cauchy ``c = 2.385``. Huber's objective is convex (one minimum); Cauchy's is
not, and IRLS finds the stationary point its start leads to, so start from a sensible fit.

References
----------
P. J. Huber, Robust Statistics, Wiley, 1981. P. W. Holland and R. E. Welsch, "Robust regression
using iteratively reweighted least-squares", Commun. Stat. Theory Methods 6(9), 1977.

Examples
--------
>>> import numpy as np
>>> A = np.column_stack([np.ones(6), np.arange(6.0)])
>>> q = A @ np.array([1.0, 2.0])
>>> q[4] += 50.0                                   # one gross outlier
>>> fit = irls_batch(A[None], q[None], np.ones((1, 6), bool), np.ones((1, 6)), estimator="cauchy")
>>> np.round(fit.x[0], 1).tolist(), bool(fit.weights[0, 4] < 0.01)   # least squares: [-1.4, 6.3]
([1.0, 2.0], True)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnss_cli.errors import UsageError
from gnss_cli.solvers.ls import ls_gain

__all__ = ["ESTIMATORS", "DEFAULT_TUNING", "m_estimator_weights", "m_estimator_rho", "IrlsResult", "irls_batch"]

F64 = NDArray[np.float64]

ESTIMATORS = ("huber", "cauchy")
"""M-estimators of :func:`m_estimator_weights`."""
DEFAULT_TUNING = {"huber": 1.345, "cauchy": 2.385}
"""Tuning constants (in units of the row sigma) with 95 % efficiency at the normal distribution."""


def _check(estimator: str, tuning: float | None) -> float:
    if estimator not in ESTIMATORS:
        raise UsageError(f"'estimator' must be one of {', '.join(ESTIMATORS)}; received {estimator!r}")
    c = DEFAULT_TUNING[estimator] if tuning is None else float(tuning)
    if not c > 0 or not np.isfinite(c):
        raise UsageError(f"'tuning' must be a positive finite number; received {tuning!r}")
    return c


def m_estimator_weights(u: F64, estimator: str, tuning: float | None = None) -> F64:
    """IRLS weights ``w(u) = psi(u) / u`` of standardized residuals ``u`` (unitless, any shape).

    ``w(0) = 1``; Huber ``min(1, k / |u|)``, Cauchy ``1 / (1 + (u / c)^2)`` (module table).

    >>> m_estimator_weights(np.array([0.0, 1.0, 2.69, -26.9]), "huber").round(3).tolist()
    [1.0, 1.0, 0.5, 0.05]
    """
    c = _check(estimator, tuning)
    a = np.abs(np.asarray(u, dtype=np.float64))
    if estimator == "huber":
        return np.minimum(1.0, c / np.maximum(a, 1e-300))
    return 1.0 / (1.0 + (a / c) ** 2)


def m_estimator_rho(u: F64, estimator: str, tuning: float | None = None) -> F64:
    """The loss ``rho(u)`` of standardized residuals ``u`` (module table; ``rho(u) ~ u^2/2`` near 0)."""
    c = _check(estimator, tuning)
    a = np.abs(np.asarray(u, dtype=np.float64))
    if estimator == "huber":
        return np.where(a <= c, 0.5 * a**2, c * a - 0.5 * c**2)
    return 0.5 * c**2 * np.log1p((a / c) ** 2)


@dataclass(frozen=True, slots=True)
class IrlsResult:
    """IRLS outcome of ``T`` epochs.

    Attributes
    ----------
    x : ``(T, m)`` the M-estimate (NaN where an epoch could not be solved).
    weights : ``(T, N)`` final robust weights ``w(u_i)`` in (0, 1] (1 for rows not reweighted,
        NaN for rows not used).
    iterations : ``(T,)`` reweighting iterations.
    converged : ``(T,)`` the weights settled within ``tolerance``.
    """

    x: F64
    weights: F64
    iterations: NDArray[np.int64]
    converged: NDArray[np.bool_]


def _wls(A: F64, q: F64, w: F64) -> F64:
    """Stacked weighted least squares ``argmin sum w_i (q_i - a_i^T x)^2`` on whitened rows (QR)."""
    root = np.sqrt(w)
    Aw, qw = A * root[..., None], q * root
    try:
        gain, _ = ls_gain(Aw)
        return np.einsum("tmn,tn->tm", gain, qw)
    except np.linalg.LinAlgError:  # a rank-deficient epoch in the stack: solve one at a time
        out = np.full(A.shape[::2], np.nan)
        for t in range(A.shape[0]):
            x, _, rank, _ = np.linalg.lstsq(Aw[t], qw[t], rcond=None)
            out[t] = x if rank == A.shape[2] else np.nan
        return out


def irls_batch(
    A: F64,
    q: F64,
    mask: NDArray[np.bool_],
    sigma: F64,
    *,
    estimator: str,
    tuning: float | None = None,
    weighted: bool = True,
    reweight: NDArray[np.bool_] | None = None,
    tolerance: float = 1e-8,
    max_iterations: int = 1000,
) -> IrlsResult:
    """M-estimate of ``A x ~ q`` for every epoch by IRLS (module Notes: the equations solved).

    Parameters
    ----------
    A : ``(T, N, m)`` design matrices.
    q : ``(T, N)`` right-hand sides (observed minus computed, in the unit of ``sigma``).
    mask : ``(T, N)`` rows used.
    sigma : ``(T, N)`` a-priori sigma of every row (same unit as ``q``), positive on used rows:
        the scale of the standardized residuals ``u = r / sigma``.
    estimator : ``"huber"`` or ``"cauchy"``.
    tuning : Huber ``k`` or Cauchy ``c`` in units of sigma (default :data:`DEFAULT_TUNING`).
    weighted : the a-priori weights are ``1 / sigma^2`` (else 1: unweighted least squares
        whose outlying rows are down-weighted).
    reweight : ``(T, N)`` rows that get robust weights (default all); the others keep
        weight 1 (exact constraints, pseudo-observations).
    tolerance : the iteration stops when no weight changes by more than this (unitless;
        default 1e-8).
    max_iterations : reweighting iterations at most (default 1000; IRLS converges linearly,
        slowly when several residuals sit near Huber's ``k``).

    Returns
    -------
    IrlsResult
        Starts from the least-squares fit with the a-priori weights (``x = 0`` residuals
        ``q`` when ``q`` holds the residuals of a previous fit: that fit's weights are the
        first ones).

    Raises
    ------
    UsageError
        Unknown estimator, non-positive tuning, tolerance or iteration limit, bad shapes.
    """
    _check(estimator, tuning)
    if not tolerance > 0 or max_iterations < 1:
        raise UsageError(f"'tolerance' must be > 0 and 'max_iterations' >= 1; received {tolerance!r}, {max_iterations!r}")
    A, q = np.asarray(A, dtype=np.float64), np.asarray(q, dtype=np.float64)
    if A.ndim != 3 or q.shape != A.shape[:2] or np.shape(mask) != q.shape or np.shape(sigma) != q.shape:
        raise UsageError(f"expected A (T, N, m) and q, mask, sigma (T, N); received {A.shape}, {q.shape}, "
                         f"{np.shape(mask)}, {np.shape(sigma)}")
    used = np.asarray(mask, dtype=bool)
    rew = used if reweight is None else used & np.asarray(reweight, dtype=bool)
    s = np.where(used, np.asarray(sigma, dtype=np.float64), 1.0)
    base = np.where(used, 1.0 / s**2 if weighted else 1.0, 0.0)
    A, q = np.where(used[..., None], A, 0.0), np.where(used, q, 0.0)
    T = A.shape[0]
    w = np.where(used, m_estimator_weights(np.where(rew, q / s, 0.0), estimator, tuning), np.nan)
    x = np.zeros((T, A.shape[2]))
    iterations = np.zeros(T, dtype=np.int64)
    converged = np.zeros(T, dtype=bool)
    for it in range(max_iterations):
        active = np.flatnonzero(~converged)
        if not active.size:
            break
        xa = _wls(A[active], q[active], base[active] * np.nan_to_num(w[active]))
        r = q[active] - np.einsum("tnm,tm->tn", A[active], xa)
        w_new = np.where(used[active], m_estimator_weights(np.where(rew[active], r / s[active], 0.0), estimator, tuning), np.nan)
        change = np.nanmax(np.abs(w_new - w[active]), axis=1, initial=0.0)
        x[active], w[active] = xa, w_new
        iterations[active] = it + 1
        converged[active] = change <= tolerance
    return IrlsResult(x=x, weights=w, iterations=iterations, converged=converged & np.isfinite(x).all(axis=1))
