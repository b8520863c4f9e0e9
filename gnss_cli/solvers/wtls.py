"""Weighted total least squares (WTLS): TLS of the row-whitened ``W^{1/2} [A q] D``.

Notes
-----
Rows are weighted by ``W^{1/2} = diag(1/σ_i)`` (``weights = 1/σ²``) and, optionally, the
columns of ``[A q]`` by ``D = diag(column_scale)``. TLS of ``W^{1/2} [A q] D`` gives
``x' = −v[0:m]/v[m]`` and ``x = diag(d_A) x' / d_q``. This is the classical
row/column-weighted TLS (Van Huffel & Vandewalle, section 3.6.2); with unit weights
and scales it is TLS. The noise gain is the TLS gain of the scaled problem mapped back:
``J = diag(d_A) J'`` per unit of ``q``; ``cov = J diag(1/w) Jᵀ``.

Examples
--------
>>> import numpy as np
>>> from gnss_cli.solvers import solve
>>> A = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
>>> res = solve("wtls", A, A @ np.array([1.0, 3.0]), weights=np.array([1.0, 4.0, 0.25]))
>>> np.round(res.x, 12).tolist()
[1.0, 3.0]
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from gnss_cli.errors import UsageError
from gnss_cli.solvers.problem import DEFAULT_RANK_RTOL, Problem
from gnss_cli.solvers.result import BatchResult
from gnss_cli.solvers.tls import DEFAULT_GAP_RTOL, DEFAULT_VM_TOL, tls_batch

__all__ = ["solve_wtls_batch"]


def solve_wtls_batch(
    problem: Problem,
    *,
    column_scale: ArrayLike | None = None,
    rank_rtol: float = DEFAULT_RANK_RTOL,
    gap_rtol: float = DEFAULT_GAP_RTOL,
    vm_tol: float = DEFAULT_VM_TOL,
) -> BatchResult:
    """Row- (and optionally column-) weighted TLS for every epoch.

    Parameters
    ----------
    problem : Problem
        Validated problem; its weights whiten the rows of ``[A q]``.
    column_scale : array_like, shape (m + 1,), optional
        Positive scales of the columns ``[A q]`` (inverse error standard deviations of
        the columns); default ones.
    rank_rtol, gap_rtol, vm_tol : float, optional
        As for :func:`gnss_cli.solvers.tls.solve_tls_batch`.

    Returns
    -------
    BatchResult
        ``cost`` = smallest squared singular value of the scaled ``[A q]``;
        ``details`` a :class:`~gnss_cli.solvers.tls.TlsDetails` of the scaled problem
        (``cov_paper`` mapped back to the unknowns of ``x``).

    Raises
    ------
    UsageError
        ``column_scale`` of the wrong shape or not finite and positive.
    """
    scale = None
    if column_scale is not None:
        m = problem.shape[2]
        scale = np.asarray(column_scale, dtype=np.float64)
        if scale.shape != (m + 1,) or not np.all(np.isfinite(scale)) or np.any(scale <= 0):
            raise UsageError(
                f"'column_scale' must be {m + 1} finite positive numbers (columns of [A q]); "
                f"received {scale.tolist()}"
            )
    return tls_batch("wtls", problem, rank_rtol, gap_rtol, vm_tol, column_scale=scale)
