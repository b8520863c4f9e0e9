"""Dilution of precision from a noise-gain matrix, and the paper's TLS formula.

Notes
-----
For any estimator with noise gain ``J = dx/dq`` the solvers return ``Q = J Jᵀ``
(DESIGN.md section 4). With the first three unknowns the receiver position and the
remaining ones clock terms, the position block is rotated to local East-North-Up,
``Q_enu = R Q_pos Rᵀ``, and::

    GDOP = sqrt(tr Q)                 (all unknowns, every clock column included)
    PDOP = sqrt(Q_EE + Q_NN + Q_UU)   HDOP = sqrt(Q_EE + Q_NN)
    VDOP = sqrt(Q_UU)                 TDOP = sqrt(Q_bb),  b = clock_index

The trace of the position block is rotation invariant, so GDOP, PDOP and TDOP do not
depend on ``ecef2enu``; HDOP and VDOP do.

References
----------
P. Misra and P. Enge, *Global Positioning System*, 2nd ed., section 6.1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnss_cli.errors import UsageError

__all__ = ["Dop", "dop_from_cov", "tls_paper_cov"]


@dataclass(frozen=True, slots=True)
class Dop:
    """DOP values, each an array of the batch shape of the covariance given."""

    gdop: NDArray[np.float64]
    pdop: NDArray[np.float64]
    hdop: NDArray[np.float64]
    vdop: NDArray[np.float64]
    tdop: NDArray[np.float64]


def _sqrt_nonneg(v: NDArray[np.float64], name: str) -> NDArray[np.float64]:
    """Square root of variances; tiny negative round-off is clipped, real negatives raise."""
    finite = np.isfinite(v)
    scale = np.max(np.abs(v[finite])) if finite.any() else 0.0
    if np.any(v[finite] < -1e-12 * max(scale, 1.0)):
        raise UsageError(f"dop_from_cov: '{name}' is negative; 'cov' is not a covariance matrix")
    return np.sqrt(np.clip(v, 0.0, None))


def dop_from_cov(
    cov: ArrayLike,
    ecef2enu: ArrayLike | None = None,
    clock_index: int = 3,
) -> Dop:
    """GDOP, PDOP, HDOP, VDOP and TDOP from noise-gain matrices.

    Parameters
    ----------
    cov : array_like, shape (..., m, m)
        Noise gain ``Q = J Jᵀ`` (unitless) of ``[position (3), clock(s)]``, m >= 4.
        NaN entries (failed epochs) propagate to NaN DOPs for those epochs.
    ecef2enu : array_like, shape (..., 3, 3) or (3, 3), optional
        Rotation taking ECEF vectors to local ENU (``v_enu = R v_ecef``). ``None`` means the
        position block is already in ENU order (east, north, up).
    clock_index : int, optional
        Column of the clock term used for TDOP (default 3).

    Returns
    -------
    Dop
        Arrays of shape ``cov.shape[:-2]``.

    Raises
    ------
    UsageError
        Wrong shapes, ``clock_index`` out of range, or negative variances.

    Examples
    --------
    >>> import numpy as np
    >>> float(dop_from_cov(np.diag([1.0, 1.0, 4.0, 1.0])).vdop)
    2.0
    """
    Q = np.asarray(cov, dtype=np.float64)
    if Q.ndim < 2 or Q.shape[-1] != Q.shape[-2] or Q.shape[-1] < 4:
        raise UsageError(
            f"dop_from_cov: 'cov' must have shape (..., m, m) with m >= 4; received shape {Q.shape}"
        )
    m = Q.shape[-1]
    if not (0 <= clock_index < m) or clock_index < 3:
        raise UsageError(
            f"dop_from_cov: 'clock_index' must be in [3, {m - 1}]; received {clock_index}"
        )
    Q_pos = Q[..., :3, :3]
    if ecef2enu is not None:
        R = np.asarray(ecef2enu, dtype=np.float64)
        if R.shape[-2:] != (3, 3):
            raise UsageError(
                f"dop_from_cov: 'ecef2enu' must have shape (..., 3, 3); received shape {R.shape}"
            )
        try:
            np.broadcast_shapes(R.shape[:-2], Q.shape[:-2])
        except ValueError:
            raise UsageError(
                f"dop_from_cov: 'ecef2enu' batch shape {R.shape[:-2]} does not broadcast "
                f"with 'cov' batch shape {Q.shape[:-2]}"
            ) from None
        if not np.all(np.isfinite(R)):
            raise UsageError("dop_from_cov: 'ecef2enu' must be finite")
        Q_pos = R @ Q_pos @ np.swapaxes(R, -1, -2)
    q_e = Q_pos[..., 0, 0]
    q_n = Q_pos[..., 1, 1]
    q_u = Q_pos[..., 2, 2]
    q_b = Q[..., clock_index, clock_index]
    tr = np.trace(Q, axis1=-2, axis2=-1)
    return Dop(
        gdop=_sqrt_nonneg(np.asarray(tr), "trace(cov)"),
        pdop=_sqrt_nonneg(np.asarray(q_e + q_n + q_u), "position variance"),
        hdop=_sqrt_nonneg(np.asarray(q_e + q_n), "horizontal variance"),
        vdop=_sqrt_nonneg(np.asarray(q_u), "vertical variance"),
        tdop=_sqrt_nonneg(np.asarray(q_b), "clock variance"),
    )


def tls_paper_cov(
    A: ArrayLike,
    sigma: ArrayLike,
    mask: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """The paper's TLS DOP matrix ``(AᵀA − σ²I)⁻¹ AᵀA (AᵀA − σ²I)⁻¹``.

    This is ``J Jᵀ`` for ``J = (AᵀA − σ²I)⁻¹ Aᵀ``, the TLS gain with the smallest
    singular value σ of ``[A q]`` held fixed. The exact TLS gain (σ varying with q) is
    the ``cov`` of ``solve("tls", ...)``.

    Parameters
    ----------
    A : array_like, shape (..., n, m)
        Design matrices (whitened if the TLS was weighted).
    sigma : array_like, shape (...)
        Smallest singular value of ``[A q]`` per problem (``TlsDetails.sigma_min``).
    mask : array_like of bool, shape (..., n), optional
        Rows to use (default all). Masked rows may hold NaN.

    Returns
    -------
    ndarray, shape (..., m, m)
        NaN where ``σ >= σ_min(A)`` (the matrix ``AᵀA − σ²I`` is not positive definite).

    Raises
    ------
    UsageError
        Wrong shapes or non-finite values in used rows / sigma.

    Notes
    -----
    Computed without forming ``AᵀA``: with ``A = Q R`` and ``K = I − σ² R⁻ᵀR⁻¹``,
    ``(AᵀA − σ²I)⁻¹ = R⁻¹ K⁻¹ R⁻ᵀ`` and the product is ``R⁻¹ K⁻² R⁻ᵀ``.
    """
    A_arr = np.asarray(A, dtype=np.float64)
    if A_arr.ndim < 2:
        raise UsageError(f"tls_paper_cov: 'A' must have shape (..., n, m); received shape {A_arr.shape}")
    *batch, n, m = A_arr.shape
    s = np.asarray(sigma, dtype=np.float64)
    if s.shape != tuple(batch):
        raise UsageError(
            f"tls_paper_cov: 'sigma' must have shape {tuple(batch)} (the batch shape of 'A'); "
            f"received shape {s.shape}"
        )
    if mask is None:
        used = np.ones(A_arr.shape[:-1], dtype=bool)
    else:
        used = np.asarray(mask)
        if used.shape != A_arr.shape[:-1] or used.dtype != np.bool_:
            raise UsageError(
                f"tls_paper_cov: 'mask' must be a bool array of shape {A_arr.shape[:-1]}; "
                f"received {used.dtype} of shape {used.shape}"
            )
    if not np.all(np.isfinite(A_arr[used])):
        raise UsageError("tls_paper_cov: 'A' has non-finite values in used rows")
    if not np.all(np.isfinite(s)) or np.any(s < 0):
        raise UsageError("tls_paper_cov: 'sigma' must be finite and >= 0")
    if n < m:
        raise UsageError(f"tls_paper_cov: 'A' needs n >= m rows; received n={n}, m={m}")
    A0 = np.where(used[..., None], A_arr, 0.0).reshape(-1, n, m)
    s2 = (s * s).reshape(-1)
    R = np.linalg.qr(A0, mode="r")
    eye = np.eye(m)
    out = np.full((A0.shape[0], m, m), np.nan)
    sv = np.linalg.svd(R, compute_uv=False)
    good = (sv[:, -1] > 0) & (sv[:, -1] ** 2 > s2)
    if good.any():
        Rg = R[good]
        r_inv = np.linalg.solve(Rg, np.broadcast_to(eye, Rg.shape))
        K = eye - s2[good, None, None] * (np.swapaxes(r_inv, -1, -2) @ r_inv)
        k_inv = np.linalg.solve(K, np.broadcast_to(eye, K.shape))
        out[good] = r_inv @ k_inv @ k_inv @ np.swapaxes(r_inv, -1, -2)
    return out.reshape(*batch, m, m)
