"""The inner problem of :mod:`gnss_cli.behavior.batch` for many short windows at once.

``B`` windows ``(N, q)`` share one shape; for a shared kernel ``r(z) I_q`` per window the dense
``Gamma = G Sigma G^T`` ``(B, n q, n q)`` is built, factored by a batched banded Cholesky and used
for the misfit and the corrected trajectory (:func:`project_batch`), as the banded per-series
projection of :mod:`gnss_cli.behavior.banded` does for one long series.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior.banded import SINGULAR_RTOL

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
    """``B`` windows ``(N, q)`` with covariances, and the index arrays of the dense ``Gamma``."""

    def __init__(self, w: F64, sig: F64, lag: int) -> None:
        n_b, n_t, q = w.shape
        self.w, self.sig, self.lag, self.q = w, sig, lag, q
        self.n = n_t - lag
        self.m = self.n * q
        n_blk = lag + 1
        self.idx = np.arange(self.n)[:, None] + np.arange(n_blk)[None, :]  # (n, l+1): j + i
        self.w_rows = w[:, self.idx]  # (B, n, l+1, q)
        self.sig_rows = sig[:, self.idx]  # (B, n, l+1, q, q)
        jj, dd, aa, cc = np.meshgrid(np.arange(self.n), np.arange(n_blk), np.arange(q), np.arange(q), indexing="ij")
        keep = jj + dd < self.n
        self.dst = (((jj + dd) * q + aa) * self.m + jj * q + cc)[keep]  # Gamma_{j+d, j}[a, c], lower part
        self.src = (((jj * n_blk + dd) * q + aa) * q + cc)[keep]
        self.kd = q * n_blk - 1  # half bandwidth of Gamma

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
    """Projections of a set of windows onto their kernels (dense factors)."""

    ok: NDArray[np.bool_]
    misfit: F64
    f: F64
    chol: F64
    lam: F64
    w_hat: F64


def _cholesky(gam: F64, kd: int) -> tuple[F64, NDArray[np.bool_]]:
    """Lower Cholesky factors of banded SPD matrices ``(B, m, m)`` (half bandwidth ``kd``).

    Column by column for all matrices at once (``m`` small, ``B`` large); only the lower
    triangle of ``gam`` is read. ``ok`` is False where a pivot is not positive or falls below
    ``SINGULAR_RTOL`` times the largest diagonal entry (the test of the banded per-series
    factorization), or where an entry overflowed; such factors are replaced by the identity.
    """
    n_b, m, _ = gam.shape
    chol = np.zeros_like(gam)
    diag_max = einsum_windows("bii->bi", gam).max(axis=1)
    ok = (diag_max > 0.0) & (diag_max < np.inf)
    floor = SINGULAR_RTOL * np.where(ok, diag_max, 1.0)
    with np.errstate(over="ignore", invalid="ignore"):  # a window whose entries overflow fails its pivot test below
        for j in range(m):
            lo, hi = max(0, j - kd), min(m, j + kd + 1)
            v = gam[:, j:hi, j] - np.matmul(chol[:, j:hi, lo:j], chol[:, j, lo:j, None])[..., 0]
            piv = v[:, 0]
            good = piv > floor
            ok &= good
            chol[:, j:hi, j] = v / np.sqrt(np.where(good, piv, 1.0))[:, None]
    ok &= np.isfinite(chol).all(axis=(1, 2))
    chol[~ok] = np.eye(m)
    return chol, ok


def solve_lower_batch(chol: F64, rhs: F64, kd: int, transpose: bool = False) -> F64:
    """``L x = rhs`` (or ``L^T x = rhs``) for banded lower factors ``(B, m, m)``; ``rhs`` ``(B, m, r)``."""
    m = chol.shape[1]
    x = np.empty_like(rhs)
    diag = einsum_windows("bii->bi", chol)
    if not transpose:
        for j in range(m):
            lo = max(0, j - kd)
            x[:, j] = (rhs[:, j] - np.matmul(chol[:, j, None, lo:j], x[:, lo:j])[:, 0]) / diag[:, j, None]
    else:
        for j in range(m - 1, -1, -1):
            hi = min(m, j + kd + 1)
            x[:, j] = (rhs[:, j] - np.matmul(chol[:, None, j + 1 : hi, j], x[:, j + 1 : hi])[:, 0]) / diag[:, j, None]
    return x


def project_batch(win: Windows, r: F64) -> Proj:
    """Misfit and corrected trajectory of every window for its shared kernel ``r`` ``(B, l+1)``."""
    n_b = r.shape[0]
    n_blk = win.lag + 1
    coef = np.zeros((n_b, n_blk, n_blk))  # [i, d] = r_{i-d} r_i
    for d in range(n_blk):
        coef[:, d:, d] = r[:, : n_blk - d] * r[:, d:]
    bands = einsum_windows("bid,bjiac->bjdac", coef, win.sig_rows)  # (B, n, l+1, q, q): Gamma_{j+d, j}
    gam = np.zeros((n_b, win.m * win.m))
    gam[:, win.dst] = bands.reshape(n_b, -1)[:, win.src]
    gam = gam.reshape(n_b, win.m, win.m)
    chol, ok = _cholesky(gam, win.kd)
    e = einsum_windows("bk,bjka->bja", r, win.w_rows).reshape(n_b, win.m)
    f = solve_lower_batch(chol, e[..., None], win.kd)[..., 0]
    lam = solve_lower_batch(chol, f[..., None], win.kd, transpose=True).reshape(n_b, win.n, win.q)
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
