"""Result types and the status table shared by every solver of the family.

A solver returns a :class:`BatchResult` (stacked over epochs) or, through
:func:`gnss_cli.solvers.solve`, a :class:`SolveResult` for one epoch. Both are frozen,
slotted dataclasses; method-specific quantities live in the typed ``details`` field.

The noise gain
--------------
``gain`` is ``J = dx/dq`` (shape ``(m, n)``), the sensitivity of the estimate to the
right-hand side, with zero columns for masked rows. ``cov`` is ``Q = J Σ Jᵀ`` with
``Σ = diag(1/weights)`` (``= J Jᵀ`` when unweighted); for LS it is exactly ``(AᵀA)⁻¹``, so
DOP is computed the same way for every method (DESIGN.md section 4).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "Status",
    "STATUS_MESSAGES",
    "BatchResult",
    "SolveResult",
    "assemble_batch",
]


class Status(enum.IntEnum):
    """Outcome of one epoch: failures negative, iteration limit zero, success positive."""

    CONVERGED = 1
    ITERATION_LIMIT = 0
    RANK_DEFICIENT = -1
    NONGENERIC = -2
    NON_FINITE = -3
    TOO_FEW_ROWS = -4
    DEGENERATE_DATA = -5

    @property
    def message(self) -> str:
        """Human-readable explanation of this status."""
        return STATUS_MESSAGES[self]


STATUS_MESSAGES: dict[Status, str] = {
    Status.CONVERGED: "solution found (closed form, or iteration converged)",
    Status.ITERATION_LIMIT: "iteration limit reached before convergence; estimate is the last iterate",
    Status.RANK_DEFICIENT: "the (weighted) design matrix over the used rows is rank deficient",
    Status.NONGENERIC: (
        "nongeneric total-least-squares problem: no unique solution "
        "(singular-value gap too small or last component of the singular vector ~ 0)"
    ),
    Status.NON_FINITE: "the computation produced non-finite values",
    Status.TOO_FEW_ROWS: "fewer usable rows than unknowns",
    Status.DEGENERATE_DATA: "the right-hand side is zero over the used rows; the estimator is undefined",
}


@dataclass(frozen=True, slots=True)
class BatchResult:
    """Solutions of ``T`` stacked epochs ``A_t x_t ≈ q_t``.

    Attributes
    ----------
    method : str
        Registry key of the solver (``"ls"``, ``"tls"``, ...).
    x : ndarray, shape (T, m)
        Estimates; NaN exactly where ``status < 0``.
    cov : ndarray, shape (T, m, m)
        Noise gain ``Q = J Σ Jᵀ``, ``Σ = diag(1/weights)`` (unitless ``J Jᵀ`` when
        unweighted). For LS/WLS exactly ``(Aᵀ W A)⁻¹``.
    gain : ndarray, shape (T, m, n)
        ``J = dx/dq``; zero columns for masked rows.
    residuals : ndarray, shape (T, n)
        ``q - A x`` for used rows, 0 for masked rows.
    cost : ndarray, shape (T,)
        The minimized objective of the method.
    n_used : ndarray of int, shape (T,)
        Number of rows used.
    rank : ndarray of int, shape (T,)
        Numerical rank of the (weighted) ``A`` over the used rows.
    cond : ndarray, shape (T,)
        2-norm condition number of the (weighted) ``A`` over the used rows.
    iterations : ndarray of int, shape (T,)
        1 for closed forms.
    status : ndarray of int8, shape (T,)
        :class:`Status` values.
    details : dataclass or None
        Method-specific quantities, e.g. :class:`gnss_cli.solvers.tls.TlsDetails`.
    """

    method: str
    x: NDArray[np.float64]
    cov: NDArray[np.float64]
    gain: NDArray[np.float64]
    residuals: NDArray[np.float64]
    cost: NDArray[np.float64]
    n_used: NDArray[np.int64]
    rank: NDArray[np.int64]
    cond: NDArray[np.float64]
    iterations: NDArray[np.int64]
    status: NDArray[np.int8]
    details: Any = None

    @property
    def success(self) -> NDArray[np.bool_]:
        """``status > 0`` per epoch, shape ``(T,)``."""
        return self.status > 0

    @property
    def messages(self) -> list[str]:
        """The status message of every epoch."""
        return [STATUS_MESSAGES[Status(int(s))] for s in self.status]


@dataclass(frozen=True, slots=True)
class SolveResult:
    """Solution of one epoch ``A x ≈ q``; fields as in :class:`BatchResult` without ``T``.

    Attributes
    ----------
    method : str
    x : ndarray, shape (m,)
    cov : ndarray, shape (m, m)
    gain : ndarray, shape (m, n)
    residuals : ndarray, shape (n,)
    cost : float
    n_used, rank : int
    cond : float
    iterations : int
    status : Status
    message : str
    details : dataclass or None
        The single-epoch slice of the batch details.
    """

    method: str
    x: NDArray[np.float64]
    cov: NDArray[np.float64]
    gain: NDArray[np.float64]
    residuals: NDArray[np.float64]
    cost: float
    n_used: int
    rank: int
    cond: float
    iterations: int
    status: Status
    message: str
    details: Any = None

    @property
    def success(self) -> bool:
        """``True`` when ``status > 0``."""
        return bool(self.status > 0)


def assemble_batch(
    method: str,
    *,
    x: NDArray[np.float64],
    gain_w: NDArray[np.float64],
    sqrt_w: NDArray[np.float64],
    A: NDArray[np.float64],
    q: NDArray[np.float64],
    used: NDArray[np.bool_],
    cost: NDArray[np.float64],
    rank: NDArray[np.int64],
    cond: NDArray[np.float64],
    iterations: NDArray[np.int64],
    status: NDArray[np.int8],
    details: Any = None,
) -> BatchResult:
    """Build a :class:`BatchResult`, blanking failed epochs with NaN.

    Parameters
    ----------
    method : str
        Registry key.
    x : ndarray, shape (T, m)
        Estimates (any values where ``status < 0``; they are replaced by NaN).
    gain_w : ndarray, shape (T, m, n)
        Gain with respect to the *whitened* right-hand side ``sqrt_w * q``; the raw gain is
        ``gain_w * sqrt_w`` and ``cov = gain_w gain_wᵀ`` (``= J diag(1/w) Jᵀ``).
    sqrt_w : ndarray, shape (T, n)
        Square roots of the weights, 0 on masked rows.
    A : ndarray, shape (T, n, m)
        Design matrices with masked rows zeroed (unweighted).
    q : ndarray, shape (T, n)
        Right-hand sides with masked rows zeroed (unweighted).
    used : ndarray of bool, shape (T, n)
    cost, rank, cond, iterations, status : ndarray, shape (T,)
    details : dataclass or None

    Returns
    -------
    BatchResult
    """
    bad = status < 0
    gain = gain_w * sqrt_w[:, None, :]
    cov = gain_w @ np.swapaxes(gain_w, -1, -2)
    cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    residuals = np.where(used, q - np.einsum("tnm,tm->tn", A, x), 0.0)
    if bad.any():  # (the copies cost more than the solve of small epochs)
        x = np.where(bad[:, None], np.nan, x)
        cov = np.where(bad[:, None, None], np.nan, cov)
        gain = np.where(bad[:, None, None], np.nan, gain)
        residuals = np.where(bad[:, None], np.nan, residuals)
        cost = np.where(bad, np.nan, cost)
    return BatchResult(
        method=method,
        x=x,
        cov=cov,
        gain=gain,
        residuals=residuals,
        cost=np.asarray(cost, dtype=np.float64),
        n_used=used.sum(axis=1).astype(np.int64),
        rank=np.asarray(rank, dtype=np.int64),
        cond=np.asarray(cond, dtype=np.float64),
        iterations=np.asarray(iterations, dtype=np.int64),
        status=np.asarray(status, dtype=np.int8),
        details=details,
    )
