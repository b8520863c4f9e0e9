"""Least squares (LS) and weighted least squares (WLS), stacked over epochs.

Notes
-----
Both solve ``min_x || W^{1/2} (A x - q) ||²`` (``W = I`` for LS) on the whitened system
with a stacked reduced QR, ``W^{1/2} A = Q R``::

    x = R⁻¹ Qᵀ W^{1/2} q,     J = dx/dq = R⁻¹ Qᵀ W^{1/2},     cov = R⁻¹ R⁻ᵀ = (Aᵀ W A)⁻¹

The normal equations are never formed; the covariance comes from the R factor
(DESIGN.md section 3, STYLE.md "Numerics").

Examples
--------
>>> import numpy as np
>>> from gnss_cli.solvers import solve
>>> A = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
>>> res = solve("ls", A, A @ np.array([2.0, -1.0]))
>>> np.round(res.x, 12).tolist()
[2.0, -1.0]
"""

from __future__ import annotations

import numpy as np

from gnss_cli.solvers.problem import DEFAULT_RANK_RTOL, Problem, finish_batch, screen
from gnss_cli.solvers.result import BatchResult

__all__ = ["solve_ls_batch", "solve_wls_batch", "ls_gain"]


def ls_gain(Aw: np.ndarray, qr: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Stacked QR-based least-squares gain of whitened systems.

    Parameters
    ----------
    Aw : ndarray, shape (T, n, m)
        Whitened design matrices of full column rank (masked rows zero).
    qr : (Q, R), optional
        Their reduced QR factors, when already computed.

    Returns
    -------
    gain_w : ndarray, shape (T, m, n)
        ``R⁻¹ Qᵀ``: the estimate is ``gain_w @ qw``.
    r_inv : ndarray, shape (T, m, m)
        ``R⁻¹``, with ``R⁻¹ R⁻ᵀ = (Awᵀ Aw)⁻¹``.
    """
    Q, R = np.linalg.qr(Aw, mode="reduced") if qr is None else qr
    m = Aw.shape[-1]
    r_inv = np.linalg.solve(R, np.broadcast_to(np.eye(m), R.shape))
    gain_w = r_inv @ np.swapaxes(Q, -1, -2)
    return gain_w, r_inv


def _solve(method: str, problem: Problem, rank_rtol: float) -> BatchResult:
    Aw = problem.Aw
    factors = np.linalg.qr(Aw, mode="reduced")  # one QR for the screen and the gain
    scr = screen(problem, rank_rtol, r=factors[1])
    work = scr.work
    qw = work.qw
    if work is not problem:  # stand-ins replaced the unsolvable epochs
        Aw = work.Aw
        factors = np.linalg.qr(Aw, mode="reduced")
    gain_w, _ = ls_gain(Aw, factors)
    x = np.einsum("tmn,tn->tm", gain_w, qw)
    rw = qw - np.einsum("tnm,tm->tn", Aw, x)
    cost = np.sum(rw * rw, axis=1)
    return finish_batch(method, problem, scr, x=x, gain_w=gain_w, cost=cost, status=scr.status)


def solve_ls_batch(problem: Problem, *, rank_rtol: float = DEFAULT_RANK_RTOL) -> BatchResult:
    """Ordinary least squares ``min ||A x - q||²`` for every epoch.

    Parameters
    ----------
    problem : Problem
        Validated problem (unit weights).
    rank_rtol : float, optional
        Relative singular-value threshold for rank deficiency (default 1e-12).

    Returns
    -------
    BatchResult
        ``cov = (AᵀA)⁻¹``, ``cost = ||q - A x||²``.
    """
    return _solve("ls", problem, rank_rtol)


def solve_wls_batch(problem: Problem, *, rank_rtol: float = DEFAULT_RANK_RTOL) -> BatchResult:
    """Weighted least squares ``min (A x - q)ᵀ W (A x - q)`` for every epoch.

    Parameters
    ----------
    problem : Problem
        Validated problem; ``W = diag(sqrt_w²)``.
    rank_rtol : float, optional
        Relative singular-value threshold for rank deficiency of ``W^{1/2} A``.

    Returns
    -------
    BatchResult
        ``cov = (Aᵀ W A)⁻¹``, ``cost`` the weighted residual sum of squares.
    """
    return _solve("wls", problem, rank_rtol)
