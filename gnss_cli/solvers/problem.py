"""The validated, masked problem every solver of the family receives.

:func:`gnss_cli.solvers.solve_batch` validates the user's arrays once and hands the solver
modules a :class:`Problem`: masked rows are zeroed (NaN there is allowed and discarded),
weights are replaced by their square roots (0 on masked rows). :func:`screen` then
computes the rank and condition number of the weighted design matrix over the used rows
and replaces the epochs that cannot be solved (too few rows, rank deficient) by a
harmless stand-in problem, so that stacked factorizations never fail on one bad epoch;
their results are blanked with NaN afterwards by
:func:`gnss_cli.solvers.result.assemble_batch`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gnss_cli.solvers.result import BatchResult, Status, assemble_batch

__all__ = ["Problem", "Screen", "screen", "finish_batch", "DEFAULT_RANK_RTOL"]

DEFAULT_RANK_RTOL = 1e-12
"""Singular values of the weighted ``A`` below ``rank_rtol * σ_max`` count as zero."""


@dataclass(frozen=True, slots=True)
class Problem:
    """Stacked epochs ``A_t x_t ≈ q_t`` after validation.

    Attributes
    ----------
    A : ndarray, shape (T, n, m)
        Design matrices, masked rows set to 0.
    q : ndarray, shape (T, n)
        Right-hand sides, masked rows set to 0.
    sqrt_w : ndarray, shape (T, n)
        Square roots of the weights (1/σ), 0 on masked rows.
    used : ndarray of bool, shape (T, n)
        Row mask (True = row used).
    exact_columns : tuple of int
        Columns of ``A`` known without error (sorted, unique).
    row_cov : ndarray, shape (T, n, k, k), or None
        Covariance of each row's noisy entries ``[noisy columns of A..., q]``; identity on
        masked rows.
    """

    A: NDArray[np.float64]
    q: NDArray[np.float64]
    sqrt_w: NDArray[np.float64]
    used: NDArray[np.bool_]
    exact_columns: tuple[int, ...] = ()
    row_cov: NDArray[np.float64] | None = None

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(T, n, m)``."""
        T, n, m = self.A.shape
        return T, n, m

    @property
    def noisy_columns(self) -> tuple[int, ...]:
        """Columns of ``A`` that carry errors, in column order."""
        m = self.A.shape[2]
        return tuple(j for j in range(m) if j not in self.exact_columns)

    @property
    def Aw(self) -> NDArray[np.float64]:
        """Row-whitened design matrices ``W^{1/2} A``, shape ``(T, n, m)``."""
        return self.sqrt_w[:, :, None] * self.A

    @property
    def qw(self) -> NDArray[np.float64]:
        """Row-whitened right-hand sides ``W^{1/2} q``, shape ``(T, n)``."""
        return self.sqrt_w * self.q


@dataclass(frozen=True, slots=True)
class Screen:
    """Outcome of :func:`screen`.

    Attributes
    ----------
    work : Problem
        The problem with unsolvable epochs replaced by a stand-in (``A = [I; 0]``, ``q = 0``).
    status : ndarray of int8, shape (T,)
        ``TOO_FEW_ROWS`` / ``RANK_DEFICIENT`` for unsolvable epochs, ``CONVERGED`` otherwise.
    ok : ndarray of bool, shape (T,)
        Epochs that can be solved.
    rank : ndarray of int, shape (T,)
    cond : ndarray, shape (T,)
        Condition number of the weighted ``A`` over the used rows (inf if singular).
    sv : ndarray, shape (T, m)
        Singular values of the weighted ``A`` over the used rows (of the original problem),
        descending.
    """

    work: Problem
    status: NDArray[np.int8]
    ok: NDArray[np.bool_]
    rank: NDArray[np.int64]
    cond: NDArray[np.float64]
    sv: NDArray[np.float64]


def screen(problem: Problem, rank_rtol: float = DEFAULT_RANK_RTOL, r: NDArray[np.float64] | None = None) -> Screen:
    """Rank, condition number and solvability of every epoch.

    Parameters
    ----------
    problem : Problem
        Validated problem with ``n >= m``.
    rank_rtol : float, optional
        Relative threshold on the singular values of ``W^{1/2} A`` (default 1e-12).
    r : ndarray, shape (T, min(n, m), m), optional
        The ``R`` factor of ``W^{1/2} A`` when the caller has it (its reduced QR).

    Returns
    -------
    Screen

    Notes
    -----
    The singular values come from the ``R`` factor of a stacked QR of ``W^{1/2} A``
    (``m x m`` per epoch), which has the same singular values as ``W^{1/2} A``.
    """
    T, n, m = problem.shape
    n_used = problem.used.sum(axis=1)
    too_few = n_used < m
    if r is None:
        r = np.linalg.qr(problem.Aw, mode="r")
    if r.shape[1] < m:
        r = np.concatenate([r, np.zeros((T, m - r.shape[1], m))], axis=1)
    s = np.linalg.svd(r, compute_uv=False)
    s_max = s[:, 0]
    rank = np.sum(s > rank_rtol * s_max[:, None], axis=1).astype(np.int64)
    rank = np.where(s_max > 0, rank, 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = np.where(s[:, -1] > 0, s_max / s[:, -1], np.inf)
    rank_def = (~too_few) & (rank < m)
    ok = ~(too_few | rank_def)
    status = np.full(T, Status.CONVERGED, dtype=np.int8)
    status[too_few] = Status.TOO_FEW_ROWS
    status[rank_def] = Status.RANK_DEFICIENT
    work = problem
    if not ok.all():
        bad = ~ok
        eye = np.zeros((n, m))
        eye[:m, :m] = np.eye(m)
        stand_used = np.zeros(n, dtype=bool)
        stand_used[:m] = True
        A = problem.A.copy()
        q = problem.q.copy()
        sqrt_w = problem.sqrt_w.copy()
        used = problem.used.copy()
        A[bad] = eye
        q[bad] = 0.0
        sqrt_w[bad] = stand_used.astype(np.float64)
        used[bad] = stand_used
        row_cov = problem.row_cov
        if row_cov is not None:
            row_cov = row_cov.copy()
            k = row_cov.shape[-1]
            row_cov[bad] = np.eye(k)
        work = replace(problem, A=A, q=q, sqrt_w=sqrt_w, used=used, row_cov=row_cov)
    return Screen(work=work, status=status, ok=ok, rank=rank, cond=cond, sv=s)


def finish_batch(
    method: str,
    problem: Problem,
    scr: Screen,
    *,
    x: NDArray[np.float64],
    gain_w: NDArray[np.float64],
    cost: NDArray[np.float64],
    status: NDArray[np.int8],
    sqrt_w: NDArray[np.float64] | None = None,
    iterations: NDArray[np.int64] | None = None,
    details: Any = None,
) -> BatchResult:
    """The ending every batch solver shares: its estimates and gains with the problem and the screen.

    ``A``, ``q`` and ``used`` come from ``problem``, ``rank`` and ``cond`` from ``scr``;
    ``sqrt_w`` defaults to the problem's weights and ``iterations`` to one per epoch (the
    closed-form solvers). See :func:`gnss_cli.solvers.result.assemble_batch`.
    """
    return assemble_batch(
        method,
        x=x,
        gain_w=gain_w,
        sqrt_w=problem.sqrt_w if sqrt_w is None else sqrt_w,
        A=problem.A,
        q=problem.q,
        used=problem.used,
        cost=cost,
        rank=scr.rank,
        cond=scr.cond,
        iterations=np.ones(x.shape[0], dtype=np.int64) if iterations is None else iterations,
        status=status,
        details=details,
    )
