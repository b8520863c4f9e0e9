"""The block-banded matrix ``G(R) Sigma G(R)^T`` of a kernel and its banded Cholesky factor.

For a kernel ``R = [R_0 ... R_l]`` with ``g`` rows and ``T`` samples, ``G(R)`` is the
``(g (T-l), q T)`` matrix whose block row ``j`` holds ``R_0 .. R_l`` at block columns
``j .. j+l``, so ``G vec(w) = vec(R H_{l+1}(w))``. With ``Sigma = blkdiag(Sigma_t)``::

    Gamma_{j+d, j} = sum_{k=0}^{l-d} R_k Sigma_{j+d+k} R_{k+d}^T,   d = 0 .. l,

a symmetric block-banded matrix with ``l`` block off-diagonals (scalar half bandwidth
``g (l+1) - 1``). It is stored in LAPACK's lower band form ``ab[i - j, j] = Gamma[i, j]`` and
factorized by ``scipy.linalg.cholesky_banded``: O(T g^3 l^2) work and O(T g^2 l) memory,
never a dense ``(T, T)`` matrix.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import NDArray
from scipy.linalg import lapack

from gnss_cli.behavior.covariance import EpochCovariance
from gnss_cli.errors import NoSolutionError

__all__ = ["SingularGramError", "BandedGram", "gram_banded", "factor_gram", "project"]

#: ``Gamma`` is treated as singular when a pivot of its Cholesky factor squared falls below
#: this fraction of the largest diagonal entry.
SINGULAR_RTOL = 1e-13


class SingularGramError(NoSolutionError):
    """``G(R) Sigma G(R)^T`` is (numerically) singular: the kernel cannot be fitted to the data."""


def gram_banded(
    blocks: NDArray[np.float64], cov: EpochCovariance, shared_r: NDArray[np.float64] | None = None
) -> NDArray[np.float64]:
    """Assemble ``G(R) Sigma G(R)^T`` in lower band storage.

    Parameters
    ----------
    blocks : ndarray, shape (l+1, g, q)
        Kernel blocks ``R_k``.
    cov : EpochCovariance
        Per-epoch covariances for ``T`` samples.
    shared_r : ndarray, shape (l+1,), optional
        When the kernel is ``r(z) I_q`` (``g = q``), its scalar coefficients: a faster path.

    Returns
    -------
    ab : ndarray, shape (g (l+1), g (T-l))
        ``ab[i - j, j] = Gamma[i, j]`` for ``i >= j``.
    """
    n_blk, g, q = blocks.shape
    lag = n_blk - 1
    n_t = cov.n_t
    n = n_t - lag
    bands: list[NDArray[np.float64]] = []
    if shared_r is not None and cov.kind != "identity":
        sig = cov.full() if cov.kind == "full" else None
        var = cov.values if cov.kind == "diag" else None
        for d in range(lag + 1):
            acc = None
            for k in range(lag + 1 - d):
                c = shared_r[k] * shared_r[k + d]
                m = k + d
                part = c * (sig[m : m + n - d] if sig is not None else var[m : m + n - d])  # type: ignore[index]
                acc = part if acc is None else acc + part
            assert acc is not None
            if var is not None:
                acc = acc[:, :, None] * np.eye(q)[None]
            bands.append(acc)
    else:
        for d in range(lag + 1):
            acc = None
            for k in range(lag + 1 - d):
                m = k + d
                part = cov.window(m, m + n - d).pair_gram(blocks[k], blocks[m])
                acc = part if acc is None else acc + part
            assert acc is not None
            bands.append(np.asarray(acc))
    width = g * (lag + 1)
    ab = np.zeros((width, n * g))
    abv = ab.reshape(width, n, g)
    aa, bb = np.meshgrid(np.arange(g), np.arange(g), indexing="ij")
    for d, band in enumerate(bands):
        off = d * g + aa - bb
        keep = off >= 0
        offs, a_idx, b_idx = off[keep], aa[keep], bb[keep]
        vals = band[:, a_idx, b_idx].T  # (n_pairs, n-d)
        abv[offs[:, None], np.arange(n - d)[None, :], b_idx[:, None]] = vals
    return ab


def factor_gram(ab: NDArray[np.float64]) -> NDArray[np.float64]:
    """Lower banded Cholesky factor of ``Gamma`` (same band storage).

    Raises
    ------
    SingularGramError
        If ``Gamma`` is not numerically positive definite.
    """
    try:
        cb = scipy.linalg.cholesky_banded(ab, lower=True, check_finite=False)
    except (np.linalg.LinAlgError, ValueError):
        raise SingularGramError("G(R) Sigma G(R)^T is singular for this kernel (Cholesky failed)") from None
    diag_max = float(np.max(ab[0])) if ab.size else 0.0
    piv = cb[0] * cb[0]
    if not np.all(np.isfinite(cb[0])) or diag_max <= 0.0 or float(np.min(piv)) <= SINGULAR_RTOL * diag_max:
        raise SingularGramError(
            "G(R) Sigma G(R)^T is numerically singular for this kernel "
            f"(smallest pivot {float(np.min(piv)) if piv.size else 0.0:.3g} vs diagonal {diag_max:.3g})"
        )
    return cb


def solve_lower(cb: NDArray[np.float64], rhs: NDArray[np.float64], transpose: bool = False) -> NDArray[np.float64]:
    """Solve ``L x = rhs`` (or ``L^T x = rhs``) with the banded factor; ``rhs`` ``(N,)`` or ``(N, k)``."""
    vec = rhs.ndim == 1
    b = rhs[:, None] if vec else rhs
    x, info = lapack.dtbtrs(cb, b, uplo="L", trans="T" if transpose else "N", diag="N")
    if info != 0:  # pragma: no cover - only for a zero pivot, excluded by factor_gram
        raise SingularGramError(f"banded triangular solve failed (LAPACK info {info})")
    return x[:, 0] if vec else x


@dataclass(frozen=True, slots=True)
class BandedGram:
    """The fixed-kernel projection of a time series (the STLS inner problem).

    Attributes
    ----------
    misfit : float
        ``e^T Gamma^{-1} e = ||f||^2`` (unit of ``w`` squared over the covariance unit).
    f : ndarray, shape (g (T-l),)
        Whitened equation error ``L^{-1} e`` (``L L^T = Gamma``).
    lam : ndarray, shape (T-l, g)
        Lagrange multipliers ``Gamma^{-1} e``.
    w_hat : ndarray, shape (T, q)
        ``w - Sigma G^T lam``, which satisfies ``G w_hat = 0``.
    chol : ndarray, shape (g (l+1), g (T-l))
        Banded lower Cholesky factor of ``Gamma``.
    """

    misfit: float
    f: NDArray[np.float64]
    lam: NDArray[np.float64]
    w_hat: NDArray[np.float64]
    chol: NDArray[np.float64]


def misfit_only(
    w: NDArray[np.float64], blocks: NDArray[np.float64], cov: EpochCovariance, shared_r: NDArray[np.float64] | None = None
) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """``(misfit, f, chol)`` without the corrected trajectory (for trial steps)."""
    n_blk, g, q = blocks.shape
    lag = n_blk - 1
    n = w.shape[0] - lag
    cb = factor_gram(gram_banded(blocks, cov, shared_r))
    r_mat = blocks.transpose(1, 0, 2).reshape(g, n_blk * q)
    windows = np.lib.stride_tricks.sliding_window_view(w, n_blk, axis=0)  # (n, q, l+1)
    e = (windows.transpose(0, 2, 1).reshape(n, n_blk * q) @ r_mat.T).reshape(n * g)
    f = solve_lower(cb, e)
    return float(f @ f), f, cb


def project(
    w: NDArray[np.float64], blocks: NDArray[np.float64], cov: EpochCovariance, shared_r: NDArray[np.float64] | None = None
) -> BandedGram:
    """Solve the inner problem ``min ||w - w_hat||_{Sigma^-1}^2 s.t. G(R) w_hat = 0`` in O(T).

    Parameters
    ----------
    w : ndarray, shape (T, q)
        Data.
    blocks : ndarray, shape (l+1, g, q)
        Kernel blocks.
    cov : EpochCovariance
        Covariances of the samples.
    shared_r : ndarray, shape (l+1,), optional
        Scalar coefficients when the kernel is ``r(z) I_q`` (fast path).

    Returns
    -------
    BandedGram

    Raises
    ------
    SingularGramError
        If ``G Sigma G^T`` is numerically singular.

    Notes
    -----
    ``M = e^T Gamma^{-1} e``, ``e = G vec(w)``, ``w_hat = w - Sigma G^T Gamma^{-1} e``.
    """
    n_blk, g, q = blocks.shape
    lag = n_blk - 1
    n = w.shape[0] - lag
    m, f, cb = misfit_only(w, blocks, cov, shared_r)
    lam = solve_lower(cb, f, transpose=True).reshape(n, g)
    u = np.zeros_like(w)
    for k in range(n_blk):
        u[k : k + n] += lam @ blocks[k]
    w_hat = w - cov.apply(u)
    return BandedGram(m, f, lam, w_hat, cb)
