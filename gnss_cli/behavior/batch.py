"""Shared-kernel STLS and fixed-kernel projections for many short windows at once.

Sliding-window smoothing (:mod:`gnss_cli.kinematic`) solves thousands of small, independent
problems of the same size (e.g. 15 epochs of ``q = 3`` coordinates). Each one is cheap; what
costs is the overhead of the many small array operations of the per-window path. Here every
array carries a leading window axis ``B`` and one pass of the algorithm serves all windows:

* :func:`project_windows` -- the projection onto a fixed shared kernel ``r(z) I_q`` (static,
  PVA) for every window;
* :func:`identify_windows` -- the weighted Hankel STLS of :func:`gnss_cli.behavior.stls` with
  ``structure="shared"``, ``max_starts=1, restarts=False``: the same starting kernels (WTLS and
  the polynomial ``(z-1)^m``, the one with the lower misfit), the same chart (``r~`` with its
  largest coefficient pinned to one, re-charted when a coordinate exceeds the threshold), the
  same damped Newton steps with the exact Hessian (Gauss--Newton where it is indefinite) and
  the same acceptance and stopping rules, evaluated window by window in lockstep.

The windows are short, so ``Gamma = G Sigma G^T`` is built dense, ``(B, n q, n q)`` with
``n = N - l``, and factored by batched Cholesky and triangular solves. Windows are processed
in chunks of :data:`CHUNK` to bound the memory.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnss_cli.behavior.banded import SINGULAR_RTOL
from gnss_cli.behavior.kernel import shared_kernel_coefficients
from gnss_cli.behavior.result import StlsStatus
from gnss_cli.behavior.descent import MU_INITIAL, MU_REJECTED
from gnss_cli.errors import UsageError

__all__ = ["WindowFits", "identify_windows", "project_windows", "CHUNK"]

F64 = NDArray[np.float64]

#: Windows per batch (bounds the memory: a few ``(CHUNK, n q, n q)`` arrays).
CHUNK = 1024


@dataclass(frozen=True, slots=True)
class WindowFits:
    """Shared kernels and corrected trajectories of ``B`` windows.

    Attributes
    ----------
    r : ndarray, shape (B, l+1)
        Ascending coefficients of ``r(z)`` (monic when ``r_l`` is not negligible, as the
        kernel of :func:`gnss_cli.behavior.stls`); NaN for infeasible windows.
    w_hat : ndarray, shape (B, N, q)
        Closest trajectories of the identified behaviors (the data for infeasible windows).
    misfit : ndarray, shape (B,)
        Weighted misfits (``inf`` for infeasible windows).
    status : ndarray of int, shape (B,)
        :class:`~gnss_cli.behavior.result.StlsStatus` values.
    iterations, n_evaluations : ndarray of int, shape (B,)
        Outer iterations and inner problems solved per window.
    """

    r: F64
    w_hat: F64
    misfit: F64
    status: NDArray[np.int64]
    iterations: NDArray[np.int64]
    n_evaluations: NDArray[np.int64]


def _full_cov(cov: ArrayLike | None, shape: tuple[int, int, int]) -> F64:
    """Covariances as ``(B, N, q, q)`` (from None, ``(B, N, q)`` variances or matrices)."""
    n_b, n_t, q = shape
    if cov is None:
        return np.broadcast_to(np.eye(q), (n_b, n_t, q, q))
    arr = np.asarray(cov, dtype=np.float64)
    if arr.shape == (n_b, n_t, q):
        return arr[..., None] * np.eye(q)
    if arr.shape == (n_b, n_t, q, q):
        return arr
    raise UsageError(f"cov: expected None, shape {(n_b, n_t, q)} or {(n_b, n_t, q, q)}, received {arr.shape}")


def _validate(w: ArrayLike, cov: ArrayLike | None, lag: int) -> tuple[F64, F64]:
    arr = np.asarray(w, dtype=np.float64)
    if arr.ndim != 3 or min(arr.shape) == 0:
        raise UsageError(f"w: expected windows of shape (B, N, q), received shape {arr.shape}")
    if isinstance(lag, bool) or not isinstance(lag, (int, np.integer)) or lag < 1:
        raise UsageError(f"lag: expected an integer >= 1, received {lag!r}")
    if arr.shape[1] < lag + 2:
        raise UsageError(f"w: expected at least lag + 2 = {lag + 2} samples per window, received {arr.shape[1]}")
    if not np.all(np.isfinite(arr)):
        raise UsageError("w: expected finite values")
    sig = _full_cov(cov, arr.shape)
    if not np.all(np.isfinite(sig)):
        raise UsageError("cov: expected finite covariances")
    return arr, sig


class _Windows:
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

    def take(self, sel: NDArray[np.intp]) -> _Windows:
        """The windows ``sel`` (index arrays shared)."""
        out = object.__new__(_Windows)
        for name in ("lag", "q", "n", "m", "kd", "idx", "dst", "src"):
            setattr(out, name, getattr(self, name))
        out.w, out.sig = self.w[sel], self.sig[sel]
        out.w_rows, out.sig_rows = self.w_rows[sel], self.sig_rows[sel]
        return out


@dataclass(slots=True)
class _Proj:
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
    factorization); such factors are replaced by the identity.
    """
    n_b, m, _ = gam.shape
    chol = np.zeros_like(gam)
    diag_max = np.einsum("bii->bi", gam).max(axis=1)
    ok = (diag_max > 0.0) & (diag_max < np.inf)
    floor = SINGULAR_RTOL * np.where(ok, diag_max, 1.0)
    for j in range(m):
        lo, hi = max(0, j - kd), min(m, j + kd + 1)
        v = gam[:, j:hi, j] - np.einsum("bik,bk->bi", chol[:, j:hi, lo:j], chol[:, j, lo:j])
        piv = v[:, 0]
        good = piv > floor
        ok &= good
        chol[:, j:hi, j] = v / np.sqrt(np.where(good, piv, 1.0))[:, None]
    chol[~ok] = np.eye(m)
    return chol, ok


def _solve_lower(chol: F64, rhs: F64, kd: int, transpose: bool = False) -> F64:
    """``L x = rhs`` (or ``L^T x = rhs``) for banded lower factors ``(B, m, m)``; ``rhs`` ``(B, m, r)``."""
    m = chol.shape[1]
    x = np.empty_like(rhs)
    diag = np.einsum("bii->bi", chol)
    if not transpose:
        for j in range(m):
            lo = max(0, j - kd)
            x[:, j] = (rhs[:, j] - np.einsum("bk,bkr->br", chol[:, j, lo:j], x[:, lo:j])) / diag[:, j, None]
    else:
        for j in range(m - 1, -1, -1):
            hi = min(m, j + kd + 1)
            x[:, j] = (rhs[:, j] - np.einsum("bk,bkr->br", chol[:, j + 1 : hi, j], x[:, j + 1 : hi])) / diag[:, j, None]
    return x


def _project(win: _Windows, r: F64) -> _Proj:
    """Misfit and corrected trajectory of every window for its shared kernel ``r`` ``(B, l+1)``."""
    n_b = r.shape[0]
    n_blk = win.lag + 1
    coef = np.zeros((n_b, n_blk, n_blk))  # [i, d] = r_{i-d} r_i
    for d in range(n_blk):
        coef[:, d:, d] = r[:, : n_blk - d] * r[:, d:]
    bands = np.einsum("bid,bjiac->bjdac", coef, win.sig_rows)  # (B, n, l+1, q, q): Gamma_{j+d, j}
    gam = np.zeros((n_b, win.m * win.m))
    gam[:, win.dst] = bands.reshape(n_b, -1)[:, win.src]
    gam = gam.reshape(n_b, win.m, win.m)
    chol, ok = _cholesky(gam, win.kd)
    e = np.einsum("bk,bjka->bja", r, win.w_rows).reshape(n_b, win.m)
    f = _solve_lower(chol, e[..., None], win.kd)[..., 0]
    lam = _solve_lower(chol, f[..., None], win.kd, transpose=True).reshape(n_b, win.n, win.q)
    u = np.zeros(win.w.shape)
    for k in range(n_blk):
        u[:, k : k + win.n] += r[:, k, None, None] * lam
    w_hat = win.w - np.matmul(win.sig, u[..., None])[..., 0]
    misfit = np.where(ok, np.einsum("bm,bm->b", f, f), np.inf)
    return _Proj(ok, misfit, f, chol, lam, w_hat)


def project_windows(w: ArrayLike, r: ArrayLike, cov: ArrayLike | None = None) -> tuple[F64, F64]:
    """Project every window onto the trajectories of a fixed shared kernel ``r(z) I_q``.

    Parameters
    ----------
    w : array_like, shape (B, N, q)
        Windows (e.g. ENU positions, m).
    r : array_like, shape (l+1,) or (B, l+1)
        Ascending coefficients of ``r(z)``, one for all windows or one per window.
    cov : array_like, optional
        Covariances ``(B, N, q, q)``, variances ``(B, N, q)`` or None (identity).

    Returns
    -------
    misfit : ndarray, shape (B,)
        ``min sum_t (w_t - w^_t)^T Sigma_t^{-1} (w_t - w^_t)`` per window (``inf`` where
        ``G Sigma G^T`` is singular).
    w_hat : ndarray, shape (B, N, q)
        The projections (the data where singular).

    Raises
    ------
    UsageError
        Invalid shapes or values.

    Examples
    --------
    >>> import numpy as np
    >>> w = np.array([[[0.0], [1.0], [0.0], [1.0]]])
    >>> m, w_hat = project_windows(w, [-1.0, 1.0])
    >>> float(m[0]), w_hat[0, :, 0].tolist()
    (1.0, [0.5, 0.5, 0.5, 0.5])
    """
    coef = np.asarray(r, dtype=np.float64)
    lag = coef.shape[-1] - 1 if coef.ndim in (1, 2) else 0
    arr, sig = _validate(w, cov, lag)
    coef = np.broadcast_to(coef, (arr.shape[0], lag + 1)) if coef.ndim == 1 else coef
    if coef.shape != (arr.shape[0], lag + 1) or not np.all(np.isfinite(coef)):
        raise UsageError(f"r: expected finite coefficients of shape ({lag + 1},) or ({arr.shape[0]}, {lag + 1})")
    misfit = np.empty(arr.shape[0])
    w_hat = np.empty_like(arr)
    for lo in range(0, arr.shape[0], CHUNK):
        sel = np.arange(lo, min(lo + CHUNK, arr.shape[0]))
        proj = _project(_Windows(arr[sel], sig[sel], lag), coef[sel])
        misfit[sel] = proj.misfit
        w_hat[sel] = np.where(proj.ok[:, None, None], proj.w_hat, arr[sel])
    return misfit, w_hat


# ---------------------------------------------------------------------- identification
def _spd_solve(a_mat: F64, rhs: F64) -> tuple[F64, NDArray[np.bool_]]:
    """Solve small SPD systems ``(K, p, p) x = (K, p)``; ``ok`` is False where ``a_mat`` is not positive definite."""
    if a_mat.shape[0] == 0:
        return rhs.copy(), np.ones(0, dtype=bool)
    ok = np.linalg.eigvalsh(a_mat)[:, 0] > 0.0
    x = np.zeros_like(rhs)
    if np.any(ok):
        x[ok] = np.linalg.solve(a_mat[ok], rhs[ok][..., None])[..., 0]
    return x, ok & np.all(np.isfinite(x), axis=1)


class _Charts:
    """Per-window charts of ``r = f * r~``: the pinned coefficient of ``r~`` and the free ones."""

    def __init__(self, fixed: F64, deg: int) -> None:
        self.deg = deg
        n_blk = fixed.size + deg
        self.conv = np.zeros((n_blk, deg + 1))  # r = conv r~
        for j in range(deg + 1):
            self.conv[j : j + fixed.size, j] = fixed
        # free index sets for every pin position
        self.free_of = np.array([[i for i in range(deg + 1) if i != p] for p in range(deg + 1)], dtype=np.intp)

    def coordinates(self, rt: F64) -> tuple[NDArray[np.intp], F64]:
        """Pins (largest coefficient) and coordinates of ``r~`` ``(K, deg+1)``."""
        pin = np.argmax(np.abs(rt), axis=1)
        scaled = rt / rt[np.arange(rt.shape[0]), pin][:, None]
        return pin, np.take_along_axis(scaled, self.free_of[pin], axis=1)

    def r_tilde(self, pin: NDArray[np.intp], theta: F64) -> F64:
        rt = np.ones((theta.shape[0], self.deg + 1))
        np.put_along_axis(rt, self.free_of[pin], theta, axis=1)
        return rt

    def conv_free(self, pin: NDArray[np.intp]) -> F64:
        """``dr/dtheta`` ``(K, l+1, n_p)``."""
        return np.transpose(self.conv[:, self.free_of[pin]], (1, 0, 2))


def _wtls_tilde(win: _Windows, fixed: F64, deg: int) -> F64:
    """WTLS ``r~`` of every window (as ``shared_wtls_tilde``: whitened by the mean covariance)."""
    c = np.linalg.cholesky(win.sig.mean(axis=1))  # (B, q, q)
    v = np.swapaxes(np.linalg.solve(c, np.swapaxes(win.w, 1, 2)), 1, 2)  # (B, N, q): C^{-1} w_t
    n_f = fixed.size - 1
    if n_f > 0:
        idx = np.arange(v.shape[1] - n_f)[:, None] + np.arange(n_f + 1)[None, :]
        v = np.einsum("btja,j->bta", v[:, idx], fixed)
    idx = np.arange(v.shape[1] - deg)[:, None] + np.arange(deg + 1)[None, :]
    stacked = np.swapaxes(v[:, idx], 2, 3).reshape(v.shape[0], -1, deg + 1)  # rows (t, a), columns shift
    return np.linalg.svd(stacked)[2][:, -1, :]


def _derivatives(win: _Windows, r: F64, conv_free: F64, proj: _Proj) -> tuple[F64, F64, F64]:
    """Half gradient, exact half Hessian and Gauss--Newton matrix (see ``descent._derivatives``)."""
    n_b, n_p = conv_free.shape[0], conv_free.shape[2]
    d_mat = np.einsum("bip,bjia->bjap", conv_free, proj.w_hat[:, win.idx]).reshape(n_b, win.m, n_p)
    jac = _solve_lower(proj.chol, d_mat, win.kd)
    grad = np.einsum("bmp,bm->bp", jac, proj.f)
    gn = np.matmul(np.swapaxes(jac, 1, 2), jac)
    u = np.zeros((n_b, win.n + win.lag, win.q, n_p))
    for i in range(win.lag + 1):
        u[:, i : i + win.n] += proj.lam[..., None] * conv_free[:, i, None, None, :]
    s = np.matmul(win.sig, u)  # Sigma_t u_t
    gs = np.einsum("bk,bjkap->bjap", r, s[:, win.idx]).reshape(n_b, win.m, n_p)
    a = _solve_lower(proj.chol, d_mat - gs, win.kd)
    hess = np.matmul(np.swapaxes(a, 1, 2), a) - np.einsum("btap,btaq->bpq", u, s)
    return grad, 0.5 * (hess + np.swapaxes(hess, 1, 2)), gn


def identify_windows(
    w: ArrayLike,
    lag: int,
    cov: ArrayLike | None = None,
    *,
    fixed_roots: Sequence[complex] = (),
    tol: float = 1e-10,
    max_iter: int = 200,
    rechart_threshold: float = 10.0,
) -> WindowFits:
    """Identify a shared kernel ``r(z) I_q`` of lag ``lag`` in every window (batched STLS).

    Parameters
    ----------
    w : array_like, shape (B, N, q)
        Windows of uniformly sampled series (e.g. ENU positions, m), ``N >= lag + 2``.
    lag : int
        Lag ``l >= 1``.
    cov : array_like, optional
        Covariances ``(B, N, q, q)``, variances ``(B, N, q)`` or None (identity).
    fixed_roots : sequence of complex
        Roots kept in every ``r(z)`` (e.g. ``(1.0,)``).
    tol, max_iter, rechart_threshold : float, int, float
        As in :func:`gnss_cli.behavior.stls`.

    Returns
    -------
    WindowFits

    Raises
    ------
    UsageError
        Invalid arguments.

    Notes
    -----
    Window ``k`` of the result equals ``stls(w[k], lag, cov=cov[k], structure="shared",
    fixed_roots=fixed_roots, tol=tol, max_iter=max_iter, max_starts=1, restarts=False)`` up
    to rounding (dense instead of banded factors), which the tests check.
    """
    arr, sig = _validate(w, cov, lag)
    if not (isinstance(tol, (float, int)) and 0.0 < tol < 1.0):
        raise UsageError(f"tol: expected a number in (0, 1), received {tol!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 0:
        raise UsageError(f"max_iter: expected a non-negative integer, received {max_iter!r}")
    fixed = shared_kernel_coefficients(fixed_roots)
    deg = int(lag) - (fixed.size - 1)
    if deg < 0:
        raise UsageError(f"fixed_roots: expected at most lag = {lag} roots, received {fixed.size - 1}")
    n_b = arr.shape[0]
    out_r = np.full((n_b, lag + 1), np.nan)
    out_w = arr.copy()
    out_m = np.full(n_b, np.inf)
    out_s = np.full(n_b, int(StlsStatus.INFEASIBLE), dtype=np.int64)
    out_i = np.zeros(n_b, dtype=np.int64)
    out_e = np.zeros(n_b, dtype=np.int64)
    consts = (MU_INITIAL, MU_REJECTED)
    for lo in range(0, n_b, CHUNK):
        sel = np.arange(lo, min(lo + CHUNK, n_b))
        res = _identify_chunk(_Windows(arr[sel], sig[sel], int(lag)), fixed, deg, float(tol), int(max_iter),
                              float(rechart_threshold), consts)
        out_r[sel], out_w[sel], out_m[sel], out_s[sel], out_i[sel], out_e[sel] = res
    return WindowFits(out_r, out_w, out_m, out_s, out_i, out_e)


def _identify_chunk(win: _Windows, fixed: F64, deg: int, tol: float, max_iter: int, rechart_threshold: float,
                    consts: tuple[float, float]) -> tuple[F64, F64, F64, NDArray[np.int64], NDArray[np.int64],
                                                          NDArray[np.int64]]:
    mu_initial, mu_rejected = consts
    n_b = win.w.shape[0]
    charts = _Charts(fixed, deg)
    status = np.full(n_b, int(StlsStatus.ITERATION_LIMIT), dtype=np.int64)
    iterations = np.zeros(n_b, dtype=np.int64)
    n_eval = np.zeros(n_b, dtype=np.int64)
    data_norm2 = np.einsum("bta,bta->b", win.w, np.linalg.solve(win.sig, win.w[..., None])[..., 0])
    exact_level = (64.0 * np.finfo(float).eps) ** 2 * np.maximum(data_norm2, np.finfo(float).tiny)

    # starting kernels: WTLS, then the polynomial (z-1)^deg; the lower misfit wins (ties: WTLS)
    starts = [_wtls_tilde(win, fixed, deg),
              np.broadcast_to(np.polynomial.polynomial.polypow([-1.0, 1.0], deg)[: deg + 1], (n_b, deg + 1))]
    best: tuple[NDArray[np.intp], F64, _Proj] | None = None
    for rt in starts:
        pin, theta = charts.coordinates(np.asarray(rt, dtype=np.float64))
        proj = _project(win, charts.r_tilde(pin, theta) @ charts.conv.T)
        n_eval += 1
        if best is None:
            best = (pin, theta, proj)
        else:
            take = proj.misfit < best[2].misfit
            best = (np.where(take, pin, best[0]), np.where(take[:, None], theta, best[1]), _merge(best[2], proj, take))
    assert best is not None
    pin, theta, state = best
    feasible = state.ok.copy()
    status[~feasible] = int(StlsStatus.INFEASIBLE)
    if deg == 0:
        status[feasible] = int(StlsStatus.DIRECT)

    active = status == int(StlsStatus.ITERATION_LIMIT)
    need = active.copy()
    mu = np.full(n_b, mu_initial)
    nu = np.full(n_b, 2.0)
    n_p = max(deg, 0)
    grad = np.zeros((n_b, n_p))
    a_mat = np.zeros((n_b, n_p, n_p))
    diag = np.ones((n_b, n_p))
    theta_norm = np.zeros(n_b)
    tiny = np.finfo(float).tiny
    while np.any(active):
        # ---- a new outer iteration where the last step was accepted (or at the start)
        dv = np.flatnonzero(active & need)
        if dv.size:
            stop = iterations[dv] >= max_iter
            active[dv[stop]] = False
            dv = dv[~stop]
            exact = state.misfit[dv] <= exact_level[dv]
            status[dv[exact]] = int(StlsStatus.EXACT)
            active[dv[exact]] = False
            dv = dv[~exact]
        if dv.size:
            sub = win.take(dv)
            r_dv = charts.r_tilde(pin[dv], theta[dv]) @ charts.conv.T
            g_dv, h_dv, gn_dv = _derivatives(sub, r_dv, charts.conv_free(pin[dv]), _take(state, dv))
            iterations[dv] += 1
            zero = np.abs(g_dv).max(axis=1) == 0.0
            newton, pd = _spd_solve(h_dv, g_dv)
            decrement = np.einsum("bp,bp->b", g_dv, newton)
            conv = zero | (pd & (decrement <= 0.1 * tol * state.misfit[dv]))
            status[dv[conv]] = int(StlsStatus.CONVERGED)
            active[dv[conv]] = False
            h_dv = np.where(pd[:, None, None], h_dv, gn_dv)
            grad[dv], a_mat[dv] = g_dv, h_dv
            dg = np.abs(np.einsum("bpp->bp", h_dv))
            diag[dv] = np.maximum(dg, 1e-12 * np.maximum(dg.max(axis=1), tiny)[:, None])
            theta_norm[dv] = np.sqrt(np.einsum("bp,bp->b", theta[dv], theta[dv]))
            need[dv] = False
        # ---- a damped step for every active window
        sv = np.flatnonzero(active)
        if sv.size == 0:
            break
        damped = a_mat[sv] + mu[sv, None, None] * (diag[sv][:, :, None] * np.eye(n_p))
        sol, solved = _spd_solve(damped, grad[sv])
        step = -sol
        predicted = np.where(solved, -2.0 * np.einsum("bp,bp->b", grad[sv], step)
                             - np.einsum("bp,bpq,bq->b", step, a_mat[sv], step), -1.0)
        tried = predicted > 0.0
        accept = np.zeros(sv.size, dtype=bool)
        trial: _Proj | None = None
        tv = sv[tried]
        if tv.size:
            new_theta = theta[tv] + step[tried]
            trial = _project(win.take(tv), charts.r_tilde(pin[tv], new_theta) @ charts.conv.T)
            n_eval[tv] += 1
            accept[tried] = trial.ok & (trial.misfit < state.misfit[tv])
        # accepted steps
        av = sv[accept]
        if av.size:
            assert trial is not None
            in_trial = np.flatnonzero(accept[tried])
            acc_trial = _take(trial, in_trial)
            s_acc = step[accept]
            rho = (state.misfit[av] - acc_trial.misfit) / predicted[accept]
            mu[av] *= np.maximum(0.1, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu[av] = 2.0
            decrease = state.misfit[av] - acc_trial.misfit
            theta[av] = theta[av] + s_acc
            _put(state, av, acc_trial)
            step_norm = np.sqrt(np.einsum("bp,bp->b", s_acc, s_acc))
            small = step_norm <= tol * (np.sqrt(np.einsum("bp,bp->b", theta[av], theta[av])) + tol)
            conv = ((decrease <= tol * state.misfit[av]) & (rho > 0.25)) | small
            status[av[conv]] = int(StlsStatus.CONVERGED)
            active[av[conv]] = False
            need[av[~conv]] = True
            re = av[~conv][np.abs(theta[av[~conv]]).max(axis=1) > rechart_threshold]
            if re.size:
                pin[re], theta[re] = charts.coordinates(charts.r_tilde(pin[re], theta[re]))
        # rejected steps
        rv = sv[~accept]
        if rv.size:
            mu[rv] = np.maximum(mu[rv] * nu[rv], mu_rejected)
            nu[rv] *= 2.0
            s_rej = step[~accept]
            tiny_step = solved[~accept] & (np.sqrt(np.einsum("bp,bp->b", s_rej, s_rej))
                                           <= 1e-15 * (theta_norm[rv] + 1e-15))
            stuck = (mu[rv] > 1e16) | tiny_step
            status[rv[stuck]] = int(StlsStatus.NO_FURTHER_DECREASE)
            active[rv[stuck]] = False
    limit = (status == int(StlsStatus.ITERATION_LIMIT)) & (state.misfit <= exact_level)
    status[limit] = int(StlsStatus.EXACT)

    r_out = charts.r_tilde(pin, theta) @ charts.conv.T
    lead = np.abs(r_out[:, -1]) > 1e-8 * np.abs(r_out).max(axis=1)
    scale = np.where(lead, r_out[:, -1], np.linalg.norm(r_out, axis=1))
    r_out = r_out / scale[:, None]
    r_out[~feasible] = np.nan
    w_hat = np.where(feasible[:, None, None], state.w_hat, win.w)
    return r_out, w_hat, np.where(feasible, state.misfit, np.inf), status, iterations, n_eval


def _take(p: _Proj, sel: NDArray[np.intp]) -> _Proj:
    return _Proj(p.ok[sel], p.misfit[sel], p.f[sel], p.chol[sel], p.lam[sel], p.w_hat[sel])


def _put(p: _Proj, sel: NDArray[np.intp], src: _Proj) -> None:
    p.ok[sel], p.misfit[sel], p.f[sel] = src.ok, src.misfit, src.f
    p.chol[sel], p.lam[sel], p.w_hat[sel] = src.chol, src.lam, src.w_hat


def _merge(a: _Proj, b: _Proj, take_b: NDArray[np.bool_]) -> _Proj:
    out = _take(a, np.arange(a.ok.size))
    _put(out, np.flatnonzero(take_b), _take(b, np.flatnonzero(take_b)))
    return out
