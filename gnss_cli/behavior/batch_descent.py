"""The lockstep damped Newton descent of :func:`gnss_cli.behavior.batch.identify_windows`.

Every window of a chunk runs the shared-structure descent of :mod:`gnss_cli.behavior.descent`
(the same starts, chart, steps, acceptance and stopping rules) with a leading window axis:
windows whose last step was accepted get new derivatives (:func:`_new_iteration`), every
active window tries a damped step (:func:`_damped_steps`), and finished windows drop out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior.batch_projection import (
    F64, Proj, Windows, einsum_windows, merge, project_batch, put, solve_lower_batch, take,
)
from gnss_cli.behavior.result import StlsStatus

__all__ = ["identify_chunk"]


def spd_solve(a_mat: F64, rhs: F64) -> tuple[F64, NDArray[np.bool_]]:
    """Solve small SPD systems ``(K, p, p) x = (K, p)``; ``ok`` is False where ``a_mat`` is not positive definite."""
    if a_mat.shape[0] == 0:
        return rhs.copy(), np.ones(0, dtype=bool)
    ok = np.linalg.eigvalsh(a_mat)[:, 0] > 0.0
    x = np.zeros_like(rhs)
    if np.any(ok):
        x[ok] = np.linalg.solve(a_mat[ok], rhs[ok][..., None])[..., 0]
    return x, ok & np.all(np.isfinite(x), axis=1)


class Charts:
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

    def r(self, pin: NDArray[np.intp], theta: F64) -> F64:
        """``r = f * r~`` of every window ``(K, l+1)``. An einsum, not ``r_tilde @ conv.T``: a
        (K, n) @ (n, m) matmul rounds a row differently with K (BLAS blocking), and a window must
        get the same kernel in any batch."""
        return einsum_windows("bp,kp->bk", self.r_tilde(pin, theta), self.conv)

    def conv_free(self, pin: NDArray[np.intp]) -> F64:
        """``dr/dtheta`` ``(K, l+1, n_p)``."""
        return np.transpose(self.conv[:, self.free_of[pin]], (1, 0, 2))


def wtls_tilde(win: Windows, fixed: F64, deg: int) -> F64:
    """WTLS ``r~`` of every window (as ``shared_wtls_tilde``: whitened by the mean covariance)."""
    c = np.linalg.cholesky(win.sig.mean(axis=1))  # (B, q, q)
    v = np.swapaxes(np.linalg.solve(c, np.swapaxes(win.w, 1, 2)), 1, 2)  # (B, N, q): C^{-1} w_t
    n_f = fixed.size - 1
    if n_f > 0:
        idx = np.arange(v.shape[1] - n_f)[:, None] + np.arange(n_f + 1)[None, :]
        v = einsum_windows("btja,j->bta", v[:, idx], fixed)
    idx = np.arange(v.shape[1] - deg)[:, None] + np.arange(deg + 1)[None, :]
    stacked = np.swapaxes(v[:, idx], 2, 3).reshape(v.shape[0], -1, deg + 1)  # rows (t, a), columns shift
    # right singular vectors only: the full U of a whole segment's (3 N, l + 1) rows is (3 N)^2 numbers
    return np.linalg.svd(stacked, full_matrices=False)[2][:, -1, :]


def derivatives_batch(win: Windows, r: F64, conv_free: F64, proj: Proj) -> tuple[F64, F64, F64]:
    """Half gradient, exact half Hessian and Gauss--Newton matrix (see ``descent.derivatives_batch``)."""
    n_b, n_p = conv_free.shape[0], conv_free.shape[2]
    d_mat = einsum_windows("bip,bjia->bjap", conv_free, proj.w_hat[:, win.idx]).reshape(n_b, win.m, n_p)
    jac = solve_lower_batch(proj.chol, d_mat)
    grad = einsum_windows("bmp,bm->bp", jac, proj.f)
    gn = np.matmul(np.swapaxes(jac, 1, 2), jac)
    u = np.zeros((n_b, win.n + win.lag, win.q, n_p))
    for i in range(win.lag + 1):
        u[:, i : i + win.n] += proj.lam[..., None] * conv_free[:, i, None, None, :]
    s = np.matmul(win.sig, u)  # Sigma_t u_t
    gs = einsum_windows("bk,bjkap->bjap", r, s[:, win.idx]).reshape(n_b, win.m, n_p)
    a = solve_lower_batch(proj.chol, d_mat - gs)
    hess = np.matmul(np.swapaxes(a, 1, 2), a) - einsum_windows("btap,btaq->bpq", u, s)
    return grad, 0.5 * (hess + np.swapaxes(hess, 1, 2)), gn


@dataclass(slots=True)
class _Lockstep:
    """The per-window state of the descent (arrays with a leading window axis, updated in place)."""

    win: Windows
    charts: Charts
    pin: NDArray[np.intp]
    theta: F64
    state: Proj
    status: NDArray[np.int64]
    iterations: NDArray[np.int64]
    n_eval: NDArray[np.int64]
    exact_level: F64
    active: NDArray[np.bool_]
    need: NDArray[np.bool_]
    mu: F64
    nu: F64
    grad: F64
    a_mat: F64
    diag: F64
    theta_norm: F64


def identify_chunk(win: Windows, fixed: F64, deg: int, tol: float, max_iter: int, rechart_threshold: float,
                   consts: tuple[float, float]) -> tuple[F64, F64, F64, NDArray[np.int64], NDArray[np.int64],
                                                         NDArray[np.int64]]:
    """Identify the shared kernels ``r = fixed * r~`` of the windows ``win`` (``deg`` free coefficients).

    ``consts`` are the initial and the rejected-step dampings. Returns ``r`` ``(B, l+1)`` (NaN
    where infeasible), ``w_hat``, misfits, statuses, iterations and evaluations per window.
    """
    mu_initial, mu_rejected = consts
    ls = _start(win, fixed, deg, mu_initial)
    feasible = ls.state.ok.copy()
    ls.status[~feasible] = int(StlsStatus.INFEASIBLE)
    if deg == 0:
        ls.status[feasible] = int(StlsStatus.DIRECT)
    ls.active = ls.status == int(StlsStatus.ITERATION_LIMIT)
    ls.need = ls.active.copy()
    while np.any(ls.active):
        _new_iteration(ls, tol, max_iter)
        if not _damped_steps(ls, tol, rechart_threshold, mu_rejected):
            break
    limit = (ls.status == int(StlsStatus.ITERATION_LIMIT)) & (ls.state.misfit <= ls.exact_level)
    ls.status[limit] = int(StlsStatus.EXACT)

    r_out = ls.charts.r(ls.pin, ls.theta)
    lead = np.abs(r_out[:, -1]) > 1e-8 * np.abs(r_out).max(axis=1)
    scale = np.where(lead, r_out[:, -1], np.linalg.norm(r_out, axis=1))
    r_out = r_out / scale[:, None]
    r_out[~feasible] = np.nan
    w_hat = np.where(feasible[:, None, None], ls.state.w_hat, win.w)
    return r_out, w_hat, np.where(feasible, ls.state.misfit, np.inf), ls.status, ls.iterations, ls.n_eval


def _start(win: Windows, fixed: F64, deg: int, mu_initial: float) -> _Lockstep:
    """The better of the WTLS and the polynomial ``(z-1)^deg`` start per window (ties: WTLS)."""
    n_b = win.w.shape[0]
    charts = Charts(fixed, deg)
    n_eval = np.zeros(n_b, dtype=np.int64)
    data_norm2 = einsum_windows("bta,bta->b", win.w, np.linalg.solve(win.sig, win.w[..., None])[..., 0])
    exact_level = (64.0 * np.finfo(float).eps) ** 2 * np.maximum(data_norm2, np.finfo(float).tiny)
    starts = [wtls_tilde(win, fixed, deg),
              np.broadcast_to(np.polynomial.polynomial.polypow([-1.0, 1.0], deg)[: deg + 1], (n_b, deg + 1))]
    best: tuple[NDArray[np.intp], F64, Proj] | None = None
    for rt in starts:
        pin, theta = charts.coordinates(np.asarray(rt, dtype=np.float64))
        proj = project_batch(win, charts.r(pin, theta))
        n_eval += 1
        if best is None:
            best = (pin, theta, proj)
        else:
            take_new = proj.misfit < best[2].misfit
            best = (np.where(take_new, pin, best[0]), np.where(take_new[:, None], theta, best[1]),
                    merge(best[2], proj, take_new))
    assert best is not None
    n_p = max(deg, 0)
    status = np.full(n_b, int(StlsStatus.ITERATION_LIMIT), dtype=np.int64)
    no_window = np.zeros(n_b, dtype=bool)
    return _Lockstep(win, charts, best[0], best[1], best[2], status, np.zeros(n_b, dtype=np.int64), n_eval,
                     exact_level, no_window, no_window.copy(), np.full(n_b, mu_initial), np.full(n_b, 2.0),
                     np.zeros((n_b, n_p)), np.zeros((n_b, n_p, n_p)), np.ones((n_b, n_p)), np.zeros(n_b))


def _new_iteration(ls: _Lockstep, tol: float, max_iter: int) -> None:
    """Derivatives of the windows whose last step was accepted (or at the start); stop the finished ones."""
    dv = np.flatnonzero(ls.active & ls.need)
    if dv.size:
        stop = ls.iterations[dv] >= max_iter
        ls.active[dv[stop]] = False
        dv = dv[~stop]
        exact = ls.state.misfit[dv] <= ls.exact_level[dv]
        ls.status[dv[exact]] = int(StlsStatus.EXACT)
        ls.active[dv[exact]] = False
        dv = dv[~exact]
    if not dv.size:
        return
    charts, pin, theta = ls.charts, ls.pin, ls.theta
    sub = ls.win.take(dv)
    r_dv = charts.r(pin[dv], theta[dv])
    g_dv, h_dv, gn_dv = derivatives_batch(sub, r_dv, charts.conv_free(pin[dv]), take(ls.state, dv))
    ls.iterations[dv] += 1
    zero = np.abs(g_dv).max(axis=1) == 0.0
    newton, pd = spd_solve(h_dv, g_dv)
    decrement = einsum_windows("bp,bp->b", g_dv, newton)
    conv = zero | (pd & (decrement <= 0.1 * tol * ls.state.misfit[dv]))
    ls.status[dv[conv]] = int(StlsStatus.CONVERGED)
    ls.active[dv[conv]] = False
    h_dv = np.where(pd[:, None, None], h_dv, gn_dv)
    ls.grad[dv], ls.a_mat[dv] = g_dv, h_dv
    dg = np.abs(einsum_windows("bpp->bp", h_dv))
    ls.diag[dv] = np.maximum(dg, 1e-12 * np.maximum(dg.max(axis=1), np.finfo(float).tiny)[:, None])
    ls.theta_norm[dv] = np.sqrt(einsum_windows("bp,bp->b", theta[dv], theta[dv]))
    ls.need[dv] = False


def _damped_steps(ls: _Lockstep, tol: float, rechart_threshold: float, mu_rejected: float) -> bool:
    """A damped step for every active window; accept the decreasing ones. False when none is active."""
    sv = np.flatnonzero(ls.active)
    if sv.size == 0:
        return False
    n_p = ls.grad.shape[1]
    damped = ls.a_mat[sv] + ls.mu[sv, None, None] * (ls.diag[sv][:, :, None] * np.eye(n_p))
    sol, solved = spd_solve(damped, ls.grad[sv])
    step = -sol
    predicted = np.where(solved, -2.0 * einsum_windows("bp,bp->b", ls.grad[sv], step)
                         - einsum_windows("bp,bpq,bq->b", step, ls.a_mat[sv], step), -1.0)
    tried = predicted > 0.0
    accept = np.zeros(sv.size, dtype=bool)
    trial: Proj | None = None
    tv = sv[tried]
    if tv.size:
        new_theta = ls.theta[tv] + step[tried]
        trial = project_batch(ls.win.take(tv), ls.charts.r(ls.pin[tv], new_theta))
        ls.n_eval[tv] += 1
        accept[tried] = trial.ok & (trial.misfit < ls.state.misfit[tv])
    if sv[accept].size:
        assert trial is not None
        _accept(ls, sv[accept], take(trial, np.flatnonzero(accept[tried])), step[accept], predicted[accept], tol,
                rechart_threshold)
    rv = sv[~accept]
    if rv.size:
        ls.mu[rv] = np.maximum(ls.mu[rv] * ls.nu[rv], mu_rejected)
        ls.nu[rv] *= 2.0
        s_rej = step[~accept]
        tiny_step = solved[~accept] & (np.sqrt(einsum_windows("bp,bp->b", s_rej, s_rej))
                                       <= 1e-15 * (ls.theta_norm[rv] + 1e-15))
        stuck = (ls.mu[rv] > 1e16) | tiny_step
        ls.status[rv[stuck]] = int(StlsStatus.NO_FURTHER_DECREASE)
        ls.active[rv[stuck]] = False
    return True


def _accept(ls: _Lockstep, av: NDArray[np.intp], acc_trial: Proj, s_acc: F64, predicted: F64, tol: float,
            rechart_threshold: float) -> None:
    """Take the accepted steps of the windows ``av``: damping update, convergence test, re-charting."""
    rho = (ls.state.misfit[av] - acc_trial.misfit) / predicted
    ls.mu[av] *= np.maximum(0.1, 1.0 - (2.0 * rho - 1.0) ** 3)
    ls.nu[av] = 2.0
    decrease = ls.state.misfit[av] - acc_trial.misfit
    theta = ls.theta
    theta[av] = theta[av] + s_acc
    put(ls.state, av, acc_trial)
    step_norm = np.sqrt(einsum_windows("bp,bp->b", s_acc, s_acc))
    small = step_norm <= tol * (np.sqrt(einsum_windows("bp,bp->b", theta[av], theta[av])) + tol)
    conv = ((decrease <= tol * ls.state.misfit[av]) & (rho > 0.25)) | small
    ls.status[av[conv]] = int(StlsStatus.CONVERGED)
    ls.active[av[conv]] = False
    ls.need[av[~conv]] = True
    re = av[~conv][np.abs(theta[av[~conv]]).max(axis=1) > rechart_threshold]
    if re.size:
        ls.pin[re], theta[re] = ls.charts.coordinates(ls.charts.r_tilde(ls.pin[re], theta[re]))
