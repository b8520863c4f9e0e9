"""The inner problem of the STLS: the closest trajectory of a fixed kernel's behavior.

With ``G = G(R)`` the block-banded matrix of the constraint ``G vec(w_hat) = 0`` and
``Gamma = G Sigma G^T = L L^T`` (banded Cholesky)::

    M(R) = e^T Gamma^{-1} e = ||L^{-1} e||^2,   e = G vec(w),
    w_hat = w - Sigma G^T Gamma^{-1} e,

in O(T) time and memory (:mod:`gnss_cli.behavior.banded`). :func:`projection_matrix` gives the
dense first-order gain ``d vec(w_hat) / d vec(w)`` of that projection for short series.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnss_cli.behavior.banded import project, solve_lower
from gnss_cli.behavior.covariance import EpochCovariance
from gnss_cli.behavior.hankel import as_series
from gnss_cli.behavior.kernel import KernelRepresentation, kernel_from
from gnss_cli.errors import UsageError

__all__ = ["misfit", "projection_matrix"]

#: Largest ``T * q`` for which :func:`projection_matrix` builds its dense result.
PROJECTION_MAX_SIZE = 6000


def misfit(
    w: ArrayLike, kernel: KernelRepresentation | ArrayLike, cov: ArrayLike | None = None
) -> tuple[float, NDArray[np.float64]]:
    """Misfit of a fixed kernel and the closest trajectory of its behavior (the inner problem).

    Parameters
    ----------
    w : array_like, shape (T, q)
        Data (e.g. ENU positions in metres), ``T > lag``.
    kernel : KernelRepresentation or array_like (p, q(l+1))
        The kernel ``R``.
    cov : array_like, optional
        Covariances ``(T, q, q)``, variances ``(T, q)`` or None (identity).

    Returns
    -------
    misfit : float
        ``min sum_t (w - w_hat)^T Sigma_t^{-1} (w - w_hat)`` over trajectories of the kernel
        (dimensionless with covariances of ``w``; unit of ``w`` squared for ``cov=None``).
    w_hat : ndarray, shape (T, q)
        The minimizer, ``w - Sigma G^T (G Sigma G^T)^{-1} G vec(w)``.

    Raises
    ------
    UsageError
        Invalid shapes or values.
    SingularGramError
        ``G Sigma G^T`` is singular for this kernel (a :class:`~gnss_cli.errors.NoSolutionError`),
        e.g. more kernel rows than the data can satisfy.

    Notes
    -----
    O(T) time and memory: ``G Sigma G^T`` is block banded and factored by a banded Cholesky.

    Examples
    --------
    >>> import numpy as np
    >>> w = np.array([[0.0], [1.0], [0.0], [1.0]])
    >>> m, w_hat = misfit(w, KernelRepresentation.static(1))
    >>> round(m, 12), w_hat.ravel().round(12).tolist()
    (1.0, [0.5, 0.5, 0.5, 0.5])
    """
    arr = as_series(w)
    n_t, q = arr.shape
    ker = kernel_from(kernel, q)
    if n_t <= ker.lag:
        raise UsageError(f"w: expected more than lag = {ker.lag} samples, received {n_t}")
    covariance = EpochCovariance.from_arg(cov, n_t, q)
    proj = project(arr, np.asarray(ker.blocks), covariance)
    return proj.misfit, proj.w_hat


def projection_matrix(
    kernel: KernelRepresentation | ArrayLike, n_t: int, cov: ArrayLike | None = None
) -> NDArray[np.float64]:
    """First-order sensitivity ``d vec(w_hat) / d vec(w)`` of the fixed-kernel projection.

    Parameters
    ----------
    kernel : KernelRepresentation or array_like (p, q(l+1))
        The (fixed) kernel.
    n_t : int
        Number of epochs ``T`` (``T * q <= 6000``: the result is dense).
    cov : array_like, optional
        Covariances ``(T, q, q)``, ``(T, q)`` or None.

    Returns
    -------
    P : ndarray, shape (T q, T q)
        ``P = I - Sigma G^T (G Sigma G^T)^{-1} G``, the ``Sigma^{-1}``-orthogonal projector onto
        the trajectories of the kernel (``vec`` stacks epochs: index ``t q + i``). For a fixed
        kernel ``w_hat = P w`` exactly; for an identified kernel it is the first-order gain with
        the kernel held fixed. The covariance of ``w_hat`` is ``P Sigma P^T = P Sigma``, whose
        ``(t, t)`` blocks give a multi-epoch DOP of the smoothed trajectory.

    Raises
    ------
    UsageError
        Invalid arguments or ``T q > 6000``.
    SingularGramError
        ``G Sigma G^T`` is singular.
    """
    if isinstance(n_t, bool) or not isinstance(n_t, (int, np.integer)) or n_t < 1:
        raise UsageError(f"n_t: expected a positive integer, received {n_t!r}")
    if isinstance(kernel, KernelRepresentation):
        ker = kernel
    else:
        ker = KernelRepresentation(np.asarray(kernel, dtype=np.float64))
    q, lag, g = ker.q, ker.lag, ker.p
    if n_t <= lag:
        raise UsageError(f"n_t: expected more than lag = {lag} epochs, received {n_t}")
    if n_t * q > PROJECTION_MAX_SIZE:
        raise UsageError(f"n_t: the dense projector needs T q <= {PROJECTION_MAX_SIZE}, received {n_t * q}")
    covariance = EpochCovariance.from_arg(cov, n_t, q)
    n = n_t - lag
    big_g = np.zeros((n * g, n_t * q))
    for j in range(n):
        big_g[j * g : (j + 1) * g, j * q : (j + lag + 1) * q] = ker.R
    # factor Gamma with a zero data series (only the factor is used)
    chol = project(np.zeros((n_t, q)), np.asarray(ker.blocks), covariance).chol
    x = solve_lower(chol, solve_lower(chol, big_g), transpose=True)  # Gamma^{-1} G
    y = (big_g.T @ x).reshape(n_t, q, n_t * q)
    if covariance.kind == "identity":
        sy = y
    elif covariance.kind == "diag":
        assert covariance.values is not None
        sy = covariance.values[:, :, None] * y
    else:
        assert covariance.values is not None
        sy = np.einsum("tab,tbk->tak", covariance.values, y)
    return np.eye(n_t * q) - sy.reshape(n_t * q, n_t * q)
