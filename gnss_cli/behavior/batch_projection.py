"""The inner problem of :mod:`gnss_cli.behavior.batch` for many short windows at once.

``B`` windows ``(N, q)`` share one shape; for a shared kernel ``r(z) I_q`` per window the band of
``Gamma = G Sigma G^T`` is built for all windows at once (LAPACK's lower band storage, one array
``(B, n q, q (l+1))``), each window's band is factored by :func:`gnss_cli.behavior.banded.factor_gram`
and the factors are used for the misfit and the corrected trajectory (:func:`project_batch`), as the
banded per-series projection of :mod:`gnss_cli.behavior.banded` does for one long series. A window's
factor and solves are LAPACK calls on that window alone, so it gets the same last bits in any batch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior.banded import SingularGramError, factor_gram, solve_lower

__all__ = ["F64", "Windows", "Proj", "project_batch", "solve_lower_batch", "take", "put", "merge", "einsum_windows"]


def einsum_windows(spec: str, *operands: NDArray[np.float64]) -> NDArray[np.float64]:
    """``np.einsum(spec, *operands)`` for operands whose subscripts start with the window axis
    ``b``, computed with at least two windows: numpy drops an axis of length 1 and then sums
    in another order, so one window alone would get other last bits than the same window in a
    batch (a file's windows are batched differently whole and in parts)."""
    subs = spec.split("->")[0].split(",")
    if any(sub.startswith("b") and op.shape[0] == 1 for sub, op in zip(subs, operands)):
        doubled = [np.concatenate((op, op)) if sub.startswith("b") else op for sub, op in zip(subs, operands)]
        return np.einsum(spec, *doubled)[:1]
    return np.einsum(spec, *operands)

F64 = NDArray[np.float64]


class Windows:
    """``B`` windows ``(N, q)`` with covariances, and the index arrays of the band of ``Gamma``."""

    def __init__(self, w: F64, sig: F64, lag: int) -> None:
        n_b, n_t, q = w.shape
        self.w, self.sig, self.lag, self.q = w, sig, lag, q
        self.n = n_t - lag
        self.m = self.n * q
        n_blk = lag + 1
        self.idx = np.arange(self.n)[:, None] + np.arange(n_blk)[None, :]  # (n, l+1): j + i
        self.w_rows = w[:, self.idx]  # (B, n, l+1, q)
        self.sig_rows = sig[:, self.idx]  # (B, n, l+1, q, q)
        self.kd = q * n_blk - 1  # half bandwidth of Gamma
        jj, dd, aa, cc = np.meshgrid(np.arange(self.n), np.arange(n_blk), np.arange(q), np.arange(q), indexing="ij")
        keep = (jj + dd < self.n) & (dd * q + aa >= cc)  # on or below the diagonal of Gamma
        # Gamma_{j+d, j}[a, c] = Gamma[row, col], row = (j+d) q + a, col = j q + c, kept at
        # ab_t[col, row - col] (the transpose of LAPACK's lower band storage, C order)
        self.dst = ((jj * q + cc) * (self.kd + 1) + dd * q + aa - cc)[keep]
        self.src = (((jj * n_blk + dd) * q + aa) * q + cc)[keep]

    def take(self, sel: NDArray[np.intp]) -> Windows:
        """The windows ``sel`` (index arrays shared)."""
        out = object.__new__(Windows)
        for name in ("lag", "q", "n", "m", "kd", "idx", "dst", "src"):
            setattr(out, name, getattr(self, name))
        out.w, out.sig = self.w[sel], self.sig[sel]
        out.w_rows, out.sig_rows = self.w_rows[sel], self.sig_rows[sel]
        return out


@dataclass(slots=True)
class Proj:
    """Projections of a set of windows onto their kernels (banded factors, as :func:`_cholesky` gives them)."""

    ok: NDArray[np.bool_]
    misfit: F64
    f: F64
    chol: F64
    lam: F64
    w_hat: F64


def _cholesky(ab_t: F64) -> tuple[F64, NDArray[np.bool_]]:
    """Lower Cholesky factors of banded SPD matrices, one LAPACK factorization per window.

    ``ab_t`` ``(B, m, kd + 1)`` holds each matrix's lower band, ``ab_t[b, j, i - j] = Gamma_b[i, j]``
    (the layout :func:`gnss_cli.behavior.banded.factor_gram` takes). The factors come back in the
    same layout, ``chol[b].T`` being LAPACK's lower band storage of ``L_b``. ``ok`` is False where
    :func:`~gnss_cli.behavior.banded.factor_gram` finds the matrix singular (a pivot not positive or
    below ``SINGULAR_RTOL`` times the largest diagonal entry, or an entry that overflowed); such
    factors are replaced by the identity.
    """
    n_b = ab_t.shape[0]
    chol = np.zeros_like(ab_t)
    ok = np.zeros(n_b, dtype=bool)
    with np.errstate(over="ignore", invalid="ignore"):  # an overflowed window fails factor_gram's tests
        for b in range(n_b):
            try:
                cb = factor_gram(ab_t[b].copy())
            except SingularGramError:
                continue
            if np.isfinite(cb).all():
                chol[b], ok[b] = cb.T, True
    chol[~ok, :, 0] = 1.0
    return chol, ok


def solve_lower_batch(chol: F64, rhs: F64, transpose: bool = False) -> F64:
    """``L x = rhs`` (or ``L^T x = rhs``) for every window's banded factor from :func:`_cholesky`
    ``(B, m, kd + 1)``; ``rhs`` ``(B, m, r)``."""
    x = np.empty_like(rhs)
    for b in range(chol.shape[0]):
        x[b] = solve_lower(chol[b].T, rhs[b], transpose=transpose)
    return x


def project_batch(win: Windows, r: F64) -> Proj:
    """Misfit and corrected trajectory of every window for its shared kernel ``r`` ``(B, l+1)``."""
    n_b = r.shape[0]
    n_blk = win.lag + 1
    coef = np.zeros((n_b, n_blk, n_blk))  # [i, d] = r_{i-d} r_i
    for d in range(n_blk):
        coef[:, d:, d] = r[:, : n_blk - d] * r[:, d:]
    bands = einsum_windows("bid,bjiac->bjdac", coef, win.sig_rows)  # (B, n, l+1, q, q): Gamma_{j+d, j}
    ab_t = np.zeros((n_b, win.m * (win.kd + 1)))
    ab_t[:, win.dst] = bands.reshape(n_b, -1)[:, win.src]
    chol, ok = _cholesky(ab_t.reshape(n_b, win.m, win.kd + 1))
    e = einsum_windows("bk,bjka->bja", r, win.w_rows).reshape(n_b, win.m)
    f = solve_lower_batch(chol, e[..., None])[..., 0]
    lam = solve_lower_batch(chol, f[..., None], transpose=True).reshape(n_b, win.n, win.q)
    u = np.zeros(win.w.shape)
    for k in range(n_blk):
        u[:, k : k + win.n] += r[:, k, None, None] * lam
    w_hat = win.w - np.matmul(win.sig, u[..., None])[..., 0]
    misfit = np.where(ok, einsum_windows("bm,bm->b", f, f), np.inf)
    return Proj(ok, misfit, f, chol, lam, w_hat)


def take(p: Proj, sel: NDArray[np.intp]) -> Proj:
    """The projections of the windows ``sel``."""
    return Proj(p.ok[sel], p.misfit[sel], p.f[sel], p.chol[sel], p.lam[sel], p.w_hat[sel])


def put(p: Proj, sel: NDArray[np.intp], src: Proj) -> None:
    """Overwrite the projections of the windows ``sel`` with ``src`` (in place)."""
    p.ok[sel], p.misfit[sel], p.f[sel] = src.ok, src.misfit, src.f
    p.chol[sel], p.lam[sel], p.w_hat[sel] = src.chol, src.lam, src.w_hat


def merge(a: Proj, b: Proj, take_b: NDArray[np.bool_]) -> Proj:
    """``b`` where ``take_b``, else ``a`` (a new set)."""
    out = take(a, np.arange(a.ok.size))
    put(out, np.flatnonzero(take_b), take(b, np.flatnonzero(take_b)))
    return out
