"""Unstructured (weighted) total least squares kernels: the SVD of the block-Hankel matrix.

This is the baseline of the behavioral identification and the starting point of the STLS:
the ``g`` left singular vectors of ``H_{l+1}(v)`` for its smallest singular values, with
``v(t) = C^{-1} w(t)`` whitened by the Cholesky factor ``C C^T = Sigma_bar`` of the *mean*
covariance, mapped back as ``R = R_v (I_{l+1} (x) C^{-1})``. The Hankel structure is ignored
(every column is treated as an independent noisy vector), so the kernel is biased; time
variation of ``Sigma_t`` enters only through the mean. The misfit reported is the exact
structured misfit of that kernel (the inner problem solved as for the STLS), so the two
methods are compared on the same criterion.

For the shared structure ``R(z) = r(z) I_q`` the scalar ``r`` is the right singular vector
of the stacked scalar Hankel matrices ``[H(v_1) ... H(v_q)]^T`` for the smallest singular
value (whitening with a constant matrix commutes with ``r(z) I_q``). Fixed roots ``f(z)``
are removed first: ``r~`` is fitted to the filtered series ``f(sigma) v``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnss_cli.behavior.banded import SingularGramError, project
from gnss_cli.behavior.covariance import EpochCovariance
from gnss_cli.behavior.hankel import as_series, hankel_rows
from gnss_cli.behavior.kernel import KernelRepresentation, shared_kernel_coefficients
from gnss_cli.behavior.result import STATUS_MESSAGES, StlsResult, StlsStatus
from gnss_cli.errors import UsageError

__all__ = ["wtls", "validate_problem"]

STRUCTURES = ("full", "shared")


def _smallest_right_vectors(a_t: NDArray[np.float64], count: int) -> NDArray[np.float64]:
    """Right singular vectors of a tall matrix ``a_t`` ``(n, Q)`` for its ``count`` smallest singular values, ``(count, Q)``."""
    if a_t.shape[0] > a_t.shape[1]:
        r_fac = np.linalg.qr(a_t, mode="r")
    else:
        r_fac = a_t
    _, _, vt = np.linalg.svd(r_fac, full_matrices=True)
    return vt[vt.shape[0] - count :]


def whitening_factor(cov: EpochCovariance) -> NDArray[np.float64]:
    """Lower Cholesky factor ``C`` of the mean covariance, ``(q, q)``."""
    return np.linalg.cholesky(cov.mean())


def full_wtls_kernel(w: NDArray[np.float64], lag: int, g: int, cov: EpochCovariance) -> NDArray[np.float64]:
    """WTLS kernel ``(g, q(l+1))`` of a ``(T, q)`` series."""
    q = w.shape[1]
    c = whitening_factor(cov)
    v = np.linalg.solve(c, w.T).T
    rows = hankel_rows(v, lag + 1)  # (n, l+1, q)
    h_t = rows.reshape(rows.shape[0], q * (lag + 1))
    r_v = _smallest_right_vectors(h_t, g)
    c_inv = np.linalg.inv(c)  # q x q, well conditioned after validation
    return r_v @ np.kron(np.eye(lag + 1), c_inv)


def shared_wtls_tilde(w: NDArray[np.float64], lag: int, fixed: NDArray[np.float64], cov: EpochCovariance) -> NDArray[np.float64]:
    """WTLS coefficients of ``r~`` (ascending, unit norm) for ``r = f r~`` with fixed factor ``f``."""
    c = whitening_factor(cov)
    v = np.linalg.solve(c, w.T).T
    n_f = fixed.size - 1
    if n_f > 0:
        v = fixed @ hankel_rows(v, n_f + 1)  # (T-n_f, q): f(sigma) v
    deg = lag - n_f
    if deg == 0:
        return np.array([1.0])
    rows = hankel_rows(v, deg + 1)  # (n, deg+1, q)
    stacked = rows.transpose(0, 2, 1).reshape(rows.shape[0] * rows.shape[2], deg + 1)
    return _smallest_right_vectors(stacked, 1)[0]


def validate_problem(
    w: ArrayLike,
    lag: int,
    order: int | None,
    cov: ArrayLike | None,
    structure: str,
    fixed_roots: Sequence[complex],
) -> tuple[NDArray[np.float64], EpochCovariance, int, NDArray[np.float64]]:
    """Validate the common arguments of :func:`stls` and :func:`wtls`.

    Returns
    -------
    w, cov, g, fixed
        The series ``(T, q)``, the covariances, the number of kernel rows and the ascending
        coefficients of the fixed factor (``[1.0]`` when there is none).

    Raises
    ------
    UsageError
        Any invalid argument, or an infeasible full-structure problem.
    """
    arr = as_series(w)
    n_t, q = arr.shape
    if isinstance(lag, bool) or not isinstance(lag, (int, np.integer)) or lag < 1:
        raise UsageError(f"lag: expected an integer >= 1, received {lag!r}")
    lag = int(lag)
    if n_t < lag + 2:
        raise UsageError(f"w: expected at least lag + 2 = {lag + 2} samples for lag {lag}, received {n_t}")
    if structure not in STRUCTURES:
        raise UsageError(f"structure: expected one of {STRUCTURES}, received {structure!r}")
    covariance = EpochCovariance.from_arg(cov, n_t, q)
    fixed = shared_kernel_coefficients(fixed_roots)
    if structure == "shared":
        if order is not None and order != q * lag:
            raise UsageError(f"order: the shared structure r(z) I_q has order q*lag = {q * lag}, received {order}")
        if fixed.size - 1 > lag:
            raise UsageError(f"fixed_roots: expected at most lag = {lag} roots, received {fixed.size - 1}")
        return arr, covariance, q, fixed
    if len(fixed_roots) > 0:
        raise UsageError("fixed_roots: only supported with structure='shared'")
    n_order = q * lag if order is None else order
    if isinstance(n_order, bool) or not isinstance(n_order, (int, np.integer)) or not 0 <= n_order < q * (lag + 1):
        raise UsageError(f"order: expected an integer in [0, q*(lag+1)) = [0, {q * (lag + 1)}), received {order!r}")
    g = q * (lag + 1) - int(n_order)
    if g * (n_t - lag) > q * n_t:
        raise UsageError(
            f"order: infeasible full-structure problem: g = q(lag+1) - order = {g} kernel rows over "
            f"T - lag = {n_t - lag} columns give {g * (n_t - lag)} constraints on q T = {q * n_t} data "
            "values, so G Sigma G^T is singular; use a larger order (g <= q), a shorter lag or structure='shared'"
        )
    return arr, covariance, g, fixed


def wtls(
    w: ArrayLike,
    lag: int,
    order: int | None = None,
    cov: ArrayLike | None = None,
    *,
    structure: str = "full",
    fixed_roots: Sequence[complex] = (),
) -> StlsResult:
    """Unstructured weighted TLS kernel of the block-Hankel matrix (the baseline method).

    Parameters
    ----------
    w : array_like, shape (T, q)
        Time series (e.g. ENU positions in metres), uniformly sampled.
    lag : int
        Kernel lag ``l >= 1``.
    order : int, optional
        Rank of the Hankel matrix ``q(l+1) - g`` (full structure); default ``q * lag``
        (``g = q`` kernel rows). Must be ``q * lag`` or None for ``structure="shared"``.
    cov : array_like, optional
        ``(T, q, q)`` or ``(T, q)`` covariances of the samples, or None (identity).
    structure : {"full", "shared"}
        General kernel or ``r(z) I_q``.
    fixed_roots : sequence of complex
        Shared structure only: roots kept in ``r`` (e.g. ``(1.0,)``).

    Returns
    -------
    StlsResult
        ``method="wtls"``, status ``DIRECT`` (or ``INFEASIBLE`` when ``G Sigma G^T`` is
        singular for the SVD kernel: then ``misfit = inf`` and ``w_hat`` is a copy of ``w``).

    Raises
    ------
    UsageError
        Invalid arguments (see :func:`validate_problem`).

    Notes
    -----
    See the module docstring for the weighting. The reported ``misfit`` and ``w_hat`` are
    those of the structured inner problem for the WTLS kernel.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(20.0)
    >>> w = np.stack([t**2, 3 * t, 1 + 0 * t], axis=1)
    >>> res = wtls(w, lag=3, structure="shared")
    >>> bool(res.misfit < 1e-20 * np.sum(w**2))
    True
    """
    arr, covariance, g, fixed = validate_problem(w, lag, order, cov, structure, fixed_roots)
    q = arr.shape[1]
    if structure == "shared":
        rt = shared_wtls_tilde(arr, lag, fixed, covariance)
        r = np.convolve(fixed, rt)
        r = r / r[-1] if abs(r[-1]) > 1e-8 * np.max(np.abs(r)) else r / np.linalg.norm(r)
        kernel = KernelRepresentation.shared(r, q)
    else:
        kernel = KernelRepresentation(full_wtls_kernel(arr, lag, g, covariance), q=q).normalized()
    try:
        proj = project(arr, np.asarray(kernel.blocks), covariance)
    except SingularGramError as exc:
        return StlsResult(kernel, arr.copy(), float("inf"), 0, StlsStatus.INFEASIBLE,
                          f"{STATUS_MESSAGES[StlsStatus.INFEASIBLE]}: {exc}", "wtls", structure, 1, 0.0)
    return StlsResult(kernel, proj.w_hat, proj.misfit, 0, StlsStatus.DIRECT,
                      STATUS_MESSAGES[StlsStatus.DIRECT], "wtls", structure, 1, 0.0)
