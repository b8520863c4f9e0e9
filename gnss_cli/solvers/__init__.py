"""Single-epoch estimators for ``A x ≈ q`` that know nothing of GNSS.

One entry point, one calling convention for every method of the family::

    from gnss_cli.solvers import solve, solve_batch
    res = solve("tls", A, q)                       # A (n, m), q (n,)
    res.x, res.cov, res.status, res.success        # cov: noise gain Q = J Jᵀ (m, m)
    solve("wls", A, q, weights=w)                  # w (n,) = 1/σ²
    solve("mtls", A, q, exact_columns=[3])         # columns known without error
    solve("stls", A, q, exact_columns=[3], row_cov=S)   # S (n, k, k)
    solve_batch("tls", A3, q3, mask)               # A3 (T, n, m), q3 (T, n), mask (T, n)

Methods (registry keys, the user's words everywhere): ``ls wls tls dls mtls stls wtls``.

Which options a method honours
------------------------------
============  =======  ==============  =======
method        weights  exact_columns   row_cov
============  =======  ==============  =======
ls            ones     --              --
wls           yes      --              --
tls           ones     --              --
dls           yes      --              --
mtls          yes      yes             --
stls          yes*     yes             yes
wtls          yes      --              --
============  =======  ==============  =======

Weights are row weights ``1/σ_i²``: for the TLS family they whiten whole rows of ``[A q]``
(``W^{1/2} [A q]``). ``stls`` takes either ``row_cov`` or ``weights`` (then
``Σ_i = I/w_i``), not both. Passing an option a method cannot honour raises
:class:`~gnss_cli.errors.UsageError` (weights of all ones are accepted everywhere).
Method-specific keyword options (tolerances, iteration limits) are listed in each
module's solver function; unknown option names raise ``UsageError``.

Modules, one job each::

    dls      Data least squares (DLS): errors in A only, q exact.
    dop      Dilution of precision from a noise-gain matrix, and the paper's TLS formula.
    kalman   Linear Kalman filter and Rauch-Tung-Striebel smoother (matrices only, no GNSS).
    ls       Least squares (LS) and weighted least squares (WLS), stacked over epochs.
    mtls     Mixed least squares – total least squares (MTLS): some columns of A are exact.
    problem  The validated, masked problem every solver of the family receives.
    result   Result types and the status table shared by every solver of the family.
    robust   M-estimators (Huber, Cauchy) by iteratively reweighted least squares, stacked over epoc...
    stls     Structured / weighted total least squares for one epoch (STLS), stacked over epochs.
    tls      Total least squares (TLS), stacked over epochs, and the gain of the TLS family.
    wtls     Weighted total least squares (WTLS): TLS of the row-whitened W^{1/2} [A q] D.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnss_cli.constants import METHOD_KEYS
from gnss_cli.errors import UsageError
from gnss_cli.solvers.dls import solve_dls_batch
from gnss_cli.solvers.ls import solve_ls_batch, solve_wls_batch
from gnss_cli.solvers.mtls import solve_mtls_batch
from gnss_cli.solvers.problem import Problem
from gnss_cli.solvers.result import STATUS_MESSAGES, BatchResult, SolveResult, Status
from gnss_cli.solvers.stls import solve_stls_batch
from gnss_cli.solvers.tls import solve_tls_batch
from gnss_cli.solvers.wtls import solve_wtls_batch

__all__ = [
    "METHODS",
    "Status",
    "STATUS_MESSAGES",
    "SolveResult",
    "BatchResult",
    "Method",
    "REGISTRY",
    "solve",
    "solve_batch",
]


@dataclass(frozen=True, slots=True)
class Method:
    """A registered solver and the options it honours."""

    name: str
    function: Callable[..., BatchResult]
    weights: bool
    exact_columns: bool
    row_cov: bool

    @property
    def options(self) -> tuple[str, ...]:
        """Names of the method-specific keyword options."""
        params = inspect.signature(self.function).parameters
        return tuple(p for p in params if p != "problem")


REGISTRY: dict[str, Method] = {
    "ls": Method("ls", solve_ls_batch, weights=False, exact_columns=False, row_cov=False),
    "wls": Method("wls", solve_wls_batch, weights=True, exact_columns=False, row_cov=False),
    "tls": Method("tls", solve_tls_batch, weights=False, exact_columns=False, row_cov=False),
    "dls": Method("dls", solve_dls_batch, weights=True, exact_columns=False, row_cov=False),
    "mtls": Method("mtls", solve_mtls_batch, weights=True, exact_columns=True, row_cov=False),
    "stls": Method("stls", solve_stls_batch, weights=True, exact_columns=True, row_cov=True),
    "wtls": Method("wtls", solve_wtls_batch, weights=True, exact_columns=False, row_cov=False),
}

METHODS: tuple[str, ...] = METHOD_KEYS
"""Registry keys in their documented order (:data:`gnss_cli.constants.METHOD_KEYS`)."""


def _lookup(method: object) -> Method:
    if not isinstance(method, str) or method not in REGISTRY:
        raise UsageError(f"'method' must be one of {', '.join(METHODS)}; received {method!r}")
    return REGISTRY[method]


def _as_float(name: str, value: ArrayLike) -> NDArray[np.float64]:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise UsageError(f"'{name}' must be a real numeric array; received {type(value).__name__}") from exc
    return arr


def _validate(
    entry: Method,
    A: ArrayLike,
    q: ArrayLike,
    mask: ArrayLike | None,
    weights: ArrayLike | None,
    exact_columns: Sequence[int],
    row_cov: ArrayLike | None,
    options: dict[str, Any],
) -> Problem:
    """Check shapes, finiteness and option compatibility; build the masked problem."""
    A_arr, q_arr, used = _validate_arrays(A, q, mask)
    m = A_arr.shape[2]
    sqrt_w = _validate_weights(entry, weights, used)
    exact = _validate_exact_columns(entry, exact_columns, m)
    cov_arr = _validate_row_cov(entry, row_cov, weights, used, m - len(exact) + 1)

    allowed = entry.options
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise UsageError(
            f"method '{entry.name}' has no option {', '.join(map(repr, unknown))}; "
            f"its options are: {', '.join(allowed) or 'none'}"
        )

    A0 = np.where(used[:, :, None], A_arr, 0.0)
    q0 = np.where(used, q_arr, 0.0)
    return Problem(A=A0, q=q0, sqrt_w=sqrt_w, used=used, exact_columns=exact, row_cov=cov_arr)


def _validate_arrays(
    A: ArrayLike, q: ArrayLike, mask: ArrayLike | None
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """``A`` ``(T, n, m)``, ``q`` ``(T, n)`` and the used rows, finite where used."""
    A_arr = _as_float("A", A)
    if A_arr.ndim != 3 or A_arr.shape[1] < 1 or A_arr.shape[2] < 1:
        raise UsageError(f"'A' must have shape (T, n, m) with n, m >= 1; received shape {A_arr.shape}")
    T, n, m = A_arr.shape
    q_arr = _as_float("q", q)
    if q_arr.shape != (T, n):
        raise UsageError(f"'q' must have shape (T, n) = {(T, n)}; received shape {q_arr.shape}")
    if mask is None:
        used = np.ones((T, n), dtype=bool)
    else:
        used = np.asarray(mask)
        if used.shape != (T, n) or used.dtype != np.bool_:
            raise UsageError(
                f"'mask' must be a bool array of shape (T, n) = {(T, n)}; "
                f"received {used.dtype} array of shape {used.shape}"
            )
    if not np.all(np.isfinite(A_arr[used])):
        t, i = np.argwhere(used & ~np.all(np.isfinite(A_arr), axis=2))[0]
        raise UsageError(f"'A' must be finite in used rows; received a non-finite value at epoch {t}, row {i}")
    if not np.all(np.isfinite(q_arr[used])):
        t, i = np.argwhere(used & ~np.isfinite(q_arr))[0]
        raise UsageError(f"'q' must be finite in used rows; received {q_arr[t, i]} at epoch {t}, row {i}")
    return A_arr, q_arr, used


def _validate_weights(entry: Method, weights: ArrayLike | None, used: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Square roots of the weights (0 on unused rows); only weighted methods take weights other than 1."""
    T, n = used.shape
    if weights is None:
        sqrt_w = used.astype(np.float64)
    else:
        w = _as_float("weights", weights)
        if w.shape != (T, n):
            raise UsageError(f"'weights' must have shape (T, n) = {(T, n)}; received shape {w.shape}")
        wu = w[used]
        if not np.all(np.isfinite(wu)) or np.any(wu <= 0):
            bad = wu[~(np.isfinite(wu) & (wu > 0))][0]
            raise UsageError(f"'weights' must be finite and > 0 in used rows; received {bad}")
        if not entry.weights and not np.all(wu == 1.0):
            raise UsageError(
                f"method '{entry.name}' does not accept weights (received weights that are not all ones); "
                f"use {'wls' if entry.name == 'ls' else 'wtls'}"
            )
        sqrt_w = np.where(used, np.sqrt(np.where(used, w, 1.0)), 0.0)
    return sqrt_w


def _validate_exact_columns(entry: Method, exact_columns: Sequence[int], m: int) -> tuple[int, ...]:
    """Sorted distinct indices of the exact columns (only for methods that take them)."""
    exact = tuple(int(j) for j in np.atleast_1d(np.asarray(exact_columns, dtype=np.int64)).tolist()) if len(exact_columns) else ()
    if exact:
        if not entry.exact_columns:
            raise UsageError(f"method '{entry.name}' does not accept 'exact_columns'; use 'mtls' or 'stls'")
        if len(set(exact)) != len(exact) or any(j < 0 or j >= m for j in exact):
            raise UsageError(
                f"'exact_columns' must be distinct column indices in [0, {m - 1}]; received {list(exact)}"
            )
        exact = tuple(sorted(exact))
    return exact


def _validate_row_cov(
    entry: Method, row_cov: ArrayLike | None, weights: ArrayLike | None, used: NDArray[np.bool_], k: int
) -> NDArray[np.float64] | None:
    """Per-row covariances ``(T, n, k, k)`` of the noisy entries, symmetric PSD where used (identity elsewhere)."""
    T, n = used.shape
    cov_arr: NDArray[np.float64] | None = None
    if row_cov is not None:
        if not entry.row_cov:
            raise UsageError(f"method '{entry.name}' does not accept 'row_cov'; use 'stls'")
        if weights is not None:
            raise UsageError("give either 'weights' or 'row_cov' to 'stls', not both")
        cov_arr = _as_float("row_cov", row_cov)
        if cov_arr.shape != (T, n, k, k):
            raise UsageError(
                f"'row_cov' must have shape (T, n, k, k) = {(T, n, k, k)} with k = m - len(exact_columns) + 1; "
                f"received shape {cov_arr.shape}"
            )
        cu = cov_arr[used]
        if not np.all(np.isfinite(cu)):
            raise UsageError("'row_cov' must be finite in used rows")
        if not np.allclose(cu, np.swapaxes(cu, -1, -2), rtol=1e-10, atol=1e-14 * max(1.0, float(np.abs(cu).max(initial=0.0)))):
            raise UsageError("'row_cov' must be symmetric in every used row")
        if np.any(cu[:, -1, -1] <= 0):
            raise UsageError("'row_cov' must have a positive variance of q (last diagonal entry) in every used row")
        if cu.size:
            ev_min = np.linalg.eigvalsh(cu)[:, 0]
            ev_max = np.abs(cu).max(axis=(1, 2))
            if np.any(ev_min < -1e-10 * ev_max):
                raise UsageError("'row_cov' must be positive semidefinite in every used row")
        cov_arr = np.where(used[:, :, None, None], cov_arr, np.eye(k))
    return cov_arr

def solve_batch(
    method: str,
    A: ArrayLike,
    q: ArrayLike,
    mask: ArrayLike | None = None,
    *,
    weights: ArrayLike | None = None,
    exact_columns: Sequence[int] = (),
    row_cov: ArrayLike | None = None,
    **options: Any,
) -> BatchResult:
    """Solve ``T`` stacked epochs ``A_t x_t ≈ q_t`` with one method.

    Parameters
    ----------
    method : str
        One of :data:`METHODS`.
    A : array_like, shape (T, n, m)
        Design matrices.
    q : array_like, shape (T, n)
        Right-hand sides (observed minus computed), in metres for GNSS.
    mask : array_like of bool, shape (T, n), optional
        True = row used (default all). Masked rows influence nothing and may hold NaN.
    weights : array_like, shape (T, n), optional
        Row weights ``1/σ²`` (default ones); see the module table for which methods take them.
    exact_columns : sequence of int, optional
        Columns of ``A`` known without error (``mtls``, ``stls``).
    row_cov : array_like, shape (T, n, k, k), optional
        ``stls`` only: covariance of ``[noisy columns of A (column order)..., q]`` per row,
        ``k = m - len(exact_columns) + 1``.
    **options
        Method-specific keywords (e.g. ``rank_rtol``, ``gap_rtol``, ``max_iterations``).

    Returns
    -------
    BatchResult
        Epochs with fewer used rows than ``m`` get status ``TOO_FEW_ROWS``; rank-deficient
        ones ``RANK_DEFICIENT``; nongeneric TLS problems ``NONGENERIC`` (their ``x`` is NaN).

    Raises
    ------
    UsageError
        Unknown method or option, an option the method cannot honour, wrong shapes,
        non-finite values in used rows, non-positive weights, invalid ``row_cov``.

    Examples
    --------
    >>> import numpy as np
    >>> A = np.tile(np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]), (2, 1, 1))
    >>> q = A @ np.array([1.0, 2.0])
    >>> solve_batch("tls", A, q).status.tolist()
    [1, 1]
    """
    entry = _lookup(method)
    problem = _validate(entry, A, q, mask, weights, exact_columns, row_cov, options)
    T, n, m = problem.shape
    if n < m:
        return _all_too_few(entry.name, problem)
    return entry.function(problem, **options)


def _all_too_few(name: str, problem: Problem) -> BatchResult:
    T, n, m = problem.shape
    return BatchResult(
        method=name,
        x=np.full((T, m), np.nan),
        cov=np.full((T, m, m), np.nan),
        gain=np.full((T, m, n), np.nan),
        residuals=np.full((T, n), np.nan),
        cost=np.full(T, np.nan),
        n_used=problem.used.sum(axis=1).astype(np.int64),
        rank=np.zeros(T, dtype=np.int64),
        cond=np.full(T, np.inf),
        iterations=np.zeros(T, dtype=np.int64),
        status=np.full(T, Status.TOO_FEW_ROWS, dtype=np.int8),
        details=None,
    )


def _slice_details(details: Any) -> Any:
    """First-epoch slice of a details dataclass (arrays indexed by [0])."""
    if details is None:
        return None
    values = {}
    for f in fields(details):
        v = getattr(details, f.name)
        if isinstance(v, np.ndarray) and v.ndim >= 1:
            v = v[0]
            if v.ndim == 0:
                v = v.item()
        values[f.name] = v
    return type(details)(**values)


def solve(
    method: str,
    A: ArrayLike,
    q: ArrayLike,
    *,
    weights: ArrayLike | None = None,
    exact_columns: Sequence[int] = (),
    row_cov: ArrayLike | None = None,
    **options: Any,
) -> SolveResult:
    """Solve one epoch ``A x ≈ q`` with one method.

    Parameters
    ----------
    method : str
        One of :data:`METHODS`.
    A : array_like, shape (n, m)
    q : array_like, shape (n,)
    weights : array_like, shape (n,), optional
        Row weights ``1/σ²``.
    exact_columns : sequence of int, optional
    row_cov : array_like, shape (n, k, k), optional
    **options
        Method-specific keywords.

    Returns
    -------
    SolveResult

    Raises
    ------
    UsageError
        As :func:`solve_batch`; every value must be finite (there is no mask).

    Examples
    --------
    >>> import numpy as np
    >>> A = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    >>> res = solve("ls", A, np.array([1.0, 1.0, 3.0]))
    >>> res.success, np.round(res.x, 6).tolist()
    (True, [1.333333, 1.333333])
    """
    A_arr = _as_float("A", A)
    if A_arr.ndim != 2:
        raise UsageError(f"'A' must have shape (n, m); received shape {A_arr.shape}")
    q_arr = _as_float("q", q)
    if q_arr.ndim != 1:
        raise UsageError(f"'q' must have shape (n,); received shape {q_arr.shape}")
    w = None if weights is None else _as_float("weights", weights)
    if w is not None and w.ndim != 1:
        raise UsageError(f"'weights' must have shape (n,); received shape {w.shape}")
    S = None if row_cov is None else _as_float("row_cov", row_cov)
    if S is not None and S.ndim != 3:
        raise UsageError(f"'row_cov' must have shape (n, k, k); received shape {S.shape}")
    res = solve_batch(
        method,
        A_arr[None],
        q_arr[None],
        None,
        weights=None if w is None else w[None],
        exact_columns=exact_columns,
        row_cov=None if S is None else S[None],
        **options,
    )
    status = Status(int(res.status[0]))
    return SolveResult(
        method=res.method,
        x=res.x[0],
        cov=res.cov[0],
        gain=res.gain[0],
        residuals=res.residuals[0],
        cost=float(res.cost[0]),
        n_used=int(res.n_used[0]),
        rank=int(res.rank[0]),
        cond=float(res.cond[0]),
        iterations=int(res.iterations[0]),
        status=status,
        message=STATUS_MESSAGES[status],
        details=_slice_details(res.details),
    )
