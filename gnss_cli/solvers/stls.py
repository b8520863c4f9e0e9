"""Structured / weighted total least squares for one epoch (STLS), stacked over epochs.

Notes
-----
Each used row ``i`` has perturbable entries ``d_i = [a_i,N, q_i]`` (the noisy columns of
``A`` in column order, then ``q``) with covariance ``Σ_i`` (``row_cov``); exact columns stay
exact. The constraint ``a_iᵀ x − q_i = 0`` per row gives the misfit (DESIGN.md section 3)::

    M(x) = Σ_i r_i² / γ_i,   r_i = a_iᵀ x − q_i,   γ_i = g_iᵀ Σ_i g_i,   g_i = [x_N, −1]

It reduces to WLS (``w_i = 1/Σ_i[q,q]``) when the geometry part of ``Σ_i`` is zero and to
MTLS when ``Σ_i = s² I`` (or ``I/w_i`` with weighted MTLS). Without ``row_cov``,
``Σ_i = I / w_i`` (``I`` without weights).

Minimization. ``M`` is minimized from the better (lower ``M``) of the WLS and MTLS
solutions by a damped Newton (Levenberg–Marquardt on the exact Hessian) iteration that
runs on all epochs at once: every epoch is a small ``m``-parameter problem, so one
iteration is a handful of stacked ``(T, m, m)`` solves and the batch is vectorized over
epochs. ``optimizer="scipy"`` instead calls :func:`scipy.optimize.least_squares` (method
``"lm"`` on the residuals ``r_i / sqrt(γ_i)``) epoch by epoch in a Python loop; that path
cannot be vectorized because scipy solves one problem per call. It is kept as an
independent reference (the tests compare the two).

Noise gain. Implicit differentiation of ``∇M(x, q) = 0`` gives ``J = dx/dq = −H⁻¹ B`` with
``H = ∇²M`` and ``B = ∂∇M/∂q``; with ``∇γ_i = 2 Sᵀ Σ_i g_i`` (``S`` scatters into the noisy
columns)::

    ∇M   = Σ 2 r a/γ − r² ∇γ/γ²
    ∇²M  = Σ 2 a aᵀ/γ − 2 r (a ∇γᵀ + ∇γ aᵀ)/γ² + 2 r² ∇γ∇γᵀ/γ³ − 2 r² SᵀΣS/γ²
    B_:i = −2 a_i/γ_i + 2 r_i ∇γ_i/γ_i²

``cov = J diag(Σ_i[q,q]) Jᵀ`` — the noise gain with respect to the pseudorange noise, the
analogue of ``J W⁻¹ Jᵀ`` (it equals the WLS covariance in the WLS reduction). The epoch is
``NONGENERIC`` when the Hessian at the solution is not positive definite.

Examples
--------
>>> import numpy as np
>>> from gnss_cli.solvers import solve
>>> A = np.column_stack([[1.0, 2.0, 3.0, 4.0], np.ones(4)])
>>> res = solve("stls", A, A @ np.array([0.5, -1.0]), exact_columns=[1])
>>> res.status.name, np.round(res.x, 10).tolist()
('CONVERGED', [0.5, -1.0])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnss_cli.errors import UsageError
from gnss_cli.solvers.ls import ls_gain
from gnss_cli.solvers.mtls import mtls_core
from gnss_cli.solvers.problem import DEFAULT_RANK_RTOL, Problem, Screen, finish_batch, screen
from gnss_cli.solvers.result import BatchResult, Status
from gnss_cli.solvers.tls import DEFAULT_GAP_RTOL, DEFAULT_VM_TOL

__all__ = ["StlsDetails", "solve_stls_batch", "stls_misfit"]


@dataclass(frozen=True, slots=True)
class StlsDetails:
    """STLS-specific results.

    Attributes
    ----------
    start : ndarray of str, shape (T,)
        ``"wls"`` or ``"mtls"``: the starting point chosen (lower misfit).
    grad_norm : ndarray, shape (T,)
        ``||∇M||`` at the solution.
    """

    start: NDArray[np.str_]
    grad_norm: NDArray[np.float64]


def _scatter(problem: Problem) -> NDArray[np.float64]:
    """``S`` (m, k−1): column j of the noisy part -> unknown index."""
    m = problem.shape[2]
    noisy = problem.noisy_columns
    S = np.zeros((m, len(noisy)))
    S[noisy, np.arange(len(noisy))] = 1.0
    return S


def _terms(
    x: NDArray[np.float64],
    A: NDArray[np.float64],
    q: NDArray[np.float64],
    used_f: NDArray[np.float64],
    Sig: NDArray[np.float64],
    S: NDArray[np.float64],
) -> tuple[NDArray[np.float64], ...]:
    """Residuals r (T,n), γ (T,n), ∇γ (T,n,m) at x (T,m)."""
    T = x.shape[0]
    g = np.concatenate([x @ S, -np.ones((T, 1))], axis=1)  # (T, k)
    Sg = np.einsum("tnij,tj->tni", Sig, g)  # (T, n, k)
    gamma = np.einsum("tni,ti->tn", Sg, g)
    grad_gamma = 2.0 * Sg[:, :, :-1] @ S.T  # (T, n, m)
    r = (np.einsum("tnm,tm->tn", A, x) - q) * used_f
    gamma = np.where(used_f > 0, gamma, 1.0)
    return r, gamma, grad_gamma


def stls_misfit(
    x: NDArray[np.float64],
    A: NDArray[np.float64],
    q: NDArray[np.float64],
    used: NDArray[np.bool_],
    row_cov: NDArray[np.float64],
    exact_columns: tuple[int, ...],
) -> NDArray[np.float64]:
    """The misfit ``M(x) = Σ r_i²/γ_i`` for stacked epochs.

    Parameters
    ----------
    x : ndarray, shape (T, m)
    A : ndarray, shape (T, n, m)
    q : ndarray, shape (T, n)
    used : ndarray of bool, shape (T, n)
    row_cov : ndarray, shape (T, n, k, k)
    exact_columns : tuple of int

    Returns
    -------
    ndarray, shape (T,)
    """
    m = A.shape[2]
    noisy = [j for j in range(m) if j not in exact_columns]
    S = np.zeros((m, len(noisy)))
    S[noisy, np.arange(len(noisy))] = 1.0
    A0 = np.where(used[:, :, None], A, 0.0)
    q0 = np.where(used, q, 0.0)
    r, gamma, _ = _terms(x, A0, q0, used.astype(np.float64), row_cov, S)
    return np.sum(r * r / gamma, axis=1)


def _grad_hess(
    x: NDArray[np.float64],
    A: NDArray[np.float64],
    q: NDArray[np.float64],
    used_f: NDArray[np.float64],
    Sig: NDArray[np.float64],
    S: NDArray[np.float64],
    SSS: NDArray[np.float64],
) -> tuple[NDArray[np.float64], ...]:
    """Misfit (T,), gradient (T,m), Hessian (T,m,m) and ∂∇M/∂q (T,m,n)."""
    r, gamma, gg = _terms(x, A, q, used_f, Sig, S)
    r = r * used_f
    inv_g = used_f / gamma
    F = np.sum(r * r * inv_g, axis=1)
    c1 = r * inv_g  # r/γ
    c2 = r * r * inv_g * inv_g  # r²/γ²
    grad = 2.0 * np.einsum("tn,tnm->tm", c1, A) - np.einsum("tn,tnm->tm", c2, gg)
    aa = np.einsum("tn,tni,tnj->tij", inv_g, A, A)
    c3 = r * inv_g * inv_g  # r/γ²
    ag = np.einsum("tn,tni,tnj->tij", c3, A, gg)
    gg2 = np.einsum("tn,tni,tnj->tij", c2 * inv_g, gg, gg)
    hss = np.einsum("tn,tnij->tij", c2, SSS)
    H = 2.0 * aa - 2.0 * (ag + np.swapaxes(ag, -1, -2)) + 2.0 * gg2 - 2.0 * hss
    B = -2.0 * np.swapaxes(A * inv_g[:, :, None], -1, -2) + 2.0 * np.swapaxes(gg * c3[:, :, None], -1, -2)
    return F, grad, 0.5 * (H + np.swapaxes(H, -1, -2)), B


def _newton(
    x0: NDArray[np.float64],
    args: tuple[NDArray[np.float64], ...],
    active: NDArray[np.bool_],
    max_iterations: int,
    xtol: float,
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.bool_]]:
    """Damped Newton on every active epoch at once; returns x, iterations, converged."""
    A, q, used_f, Sig, S, SSS = args
    T, m = x0.shape
    x = x0.copy()
    lam = np.full(T, 1e-6)
    its = np.zeros(T, dtype=np.int64)
    conv = ~active
    eye = np.eye(m)
    for _ in range(max_iterations):
        idx = np.flatnonzero(~conv)
        if idx.size == 0:
            break
        sub = tuple(a[idx] for a in (A, q, used_f, Sig)) + (S, SSS[idx])
        xi = x[idx]
        F, grad, H, _ = _grad_hess(xi, *sub)
        its[idx] += 1
        scale = np.maximum(np.abs(np.diagonal(H, axis1=1, axis2=2)).max(axis=1), 1e-300)
        accepted = np.zeros(idx.size, dtype=bool)
        step = np.zeros_like(xi)
        li = lam[idx]
        for _try in range(30):
            todo = ~accepted
            if not todo.any():
                break
            Hd = H[todo] + (li[todo] * scale[todo])[:, None, None] * eye
            ev = np.linalg.eigvalsh(Hd)[:, 0]
            pd = ev > 0
            Hd = np.where(pd[:, None, None], Hd, eye)
            st = -np.linalg.solve(Hd, grad[todo][:, :, None])[:, :, 0]
            xt = xi[todo] + st
            Ft = _grad_hess(xt, *(a[todo] for a in sub[:4]), S, sub[5][todo])[0]
            # a relative slack of a few ulps lets the last Newton steps through where the
            # misfit is flat to rounding (x is then resolved to ~eps, not ~sqrt(eps))
            ok = pd & np.isfinite(Ft) & (Ft <= F[todo] * (1.0 + 1e-13) + 1e-300)
            tidx = np.flatnonzero(todo)
            accepted[tidx[ok]] = True
            step[tidx[ok]] = st[ok]
            li[tidx[ok]] = np.maximum(li[tidx[ok]] / 10.0, 1e-12)
            li[tidx[~ok]] *= 10.0
        lam[idx] = li
        x[idx] = xi + step
        small = np.linalg.norm(step, axis=1) <= xtol * (1.0 + np.linalg.norm(xi, axis=1))
        stuck = ~accepted
        conv[idx[small | stuck]] = True
    converged = conv & active
    return x, its, converged


def _scipy_loop(
    x0: NDArray[np.float64],
    args: tuple[NDArray[np.float64], ...],
    active: NDArray[np.bool_],
    max_iterations: int,
    xtol: float,
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.bool_]]:
    """Reference path: scipy.optimize.least_squares per epoch (a Python loop)."""
    A, q, used_f, Sig, S, _ = args
    T, m = x0.shape
    x = x0.copy()
    its = np.zeros(T, dtype=np.int64)
    converged = np.zeros(T, dtype=bool)
    for t in np.flatnonzero(active):
        u = used_f[t] > 0
        At, qt, St = A[t][u], q[t][u], Sig[t][u]

        def fun(xx: NDArray[np.float64], At=At, qt=qt, St=St) -> NDArray[np.float64]:
            r, gamma, _ = _terms(xx[None], At[None], qt[None], np.ones((1, At.shape[0])), St[None], S)
            return (r / np.sqrt(gamma))[0]

        def jac(xx: NDArray[np.float64], At=At, qt=qt, St=St) -> NDArray[np.float64]:
            r, gamma, gg = _terms(xx[None], At[None], qt[None], np.ones((1, At.shape[0])), St[None], S)
            sq = np.sqrt(gamma)[0]
            return At / sq[:, None] - (r[0] / (2.0 * sq**3))[:, None] * gg[0]

        from scipy.optimize import least_squares  # imported by stls only

        method = "lm" if At.shape[0] >= m else "trf"
        sol = least_squares(
            fun, x0[t], jac=jac, method=method, xtol=xtol, ftol=1e-15, gtol=1e-15,
            max_nfev=max_iterations * (m + 1) * 10,
        )
        x[t] = sol.x
        its[t] = sol.nfev
        converged[t] = sol.status > 0
    return x, its, converged


def solve_stls_batch(
    problem: Problem,
    *,
    optimizer: str = "newton",
    max_iterations: int = 50,
    xtol: float = 1e-12,
    rank_rtol: float = DEFAULT_RANK_RTOL,
    gap_rtol: float = DEFAULT_GAP_RTOL,
    vm_tol: float = DEFAULT_VM_TOL,
) -> BatchResult:
    """Single-epoch structured TLS for every epoch.

    Parameters
    ----------
    problem : Problem
        Validated problem. ``row_cov`` (T, n, k, k) gives ``Σ_i``; without it
        ``Σ_i = I / w_i`` from the weights (``I`` if unweighted).
    optimizer : {"newton", "scipy"}, optional
        ``"newton"`` (default): damped Newton vectorized over epochs. ``"scipy"``:
        :func:`scipy.optimize.least_squares` epoch by epoch (slow reference).
    max_iterations : int, optional
        Newton iteration limit (default 50); epochs that hit it get
        ``Status.ITERATION_LIMIT`` with the last iterate.
    xtol : float, optional
        Convergence when ``||Δx|| <= xtol (1 + ||x||)`` (default 1e-12).
    rank_rtol, gap_rtol, vm_tol : float, optional
        Thresholds of the rank screen and of the MTLS starting point.

    Returns
    -------
    BatchResult
        ``cost = M(x)``; ``details`` a :class:`StlsDetails`.

    Raises
    ------
    UsageError
        Unknown ``optimizer`` or a non-positive ``max_iterations`` / ``xtol``.
    """
    if optimizer not in ("newton", "scipy"):
        raise UsageError(f"'optimizer' must be 'newton' or 'scipy'; received {optimizer!r}")
    if int(max_iterations) < 1:
        raise UsageError(f"'max_iterations' must be >= 1; received {max_iterations}")
    if not xtol > 0:
        raise UsageError(f"'xtol' must be > 0; received {xtol}")
    scr, args, var_q, sqrt_wq = _whitened_problem(problem, rank_rtol)
    x0, start = _starting_points(problem, scr, args, gap_rtol, vm_tol)
    run = _newton if optimizer == "newton" else _scipy_loop
    x, its, converged = run(x0, args, scr.ok, int(max_iterations), float(xtol))
    F, grad, J, pd = _noise_gain(x, args, scr.ok)
    status = scr.status.copy()
    status[scr.ok & ~converged] = Status.ITERATION_LIMIT
    status[scr.ok & ~pd] = Status.NONGENERIC
    finite = np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(J), axis=(1, 2))
    status[scr.ok & ~finite] = Status.NON_FINITE
    sd_q = np.where(problem.used, np.sqrt(var_q), 0.0)
    gain_w = J * sd_q[:, None, :]
    details = StlsDetails(start=start, grad_norm=np.linalg.norm(grad, axis=1))
    return finish_batch(
        "stls", problem, scr, x=np.where(np.isfinite(x), x, 0.0), gain_w=np.where(np.isfinite(gain_w), gain_w, 0.0),
        cost=F, status=status, sqrt_w=sqrt_wq, iterations=its, details=details,
    )


def _whitened_problem(
    problem: Problem, rank_rtol: float
) -> tuple[Screen, tuple[NDArray[np.float64], ...], NDArray[np.float64], NDArray[np.float64]]:
    """Screen of the problem weighted by ``1 / var(q_i)`` and the arguments of :func:`_grad_hess`.

    ``Σ_i`` is ``row_cov`` or ``I / w_i`` from the weights. Returns the screen, the arguments,
    ``var(q_i)`` ``(T, n)`` and the row weights ``1 / sd(q_i)`` (0 on masked rows).
    """
    T, n, m = problem.shape
    k = m - len(problem.exact_columns) + 1
    if problem.row_cov is None:
        w = np.where(problem.used, problem.sqrt_w**2, 1.0)
        Sig = np.eye(k)[None, None] / w[:, :, None, None]
    else:
        Sig = problem.row_cov
    var_q = Sig[:, :, -1, -1]
    sqrt_wq = np.where(problem.used, 1.0 / np.sqrt(var_q), 0.0)
    base = Problem(
        A=problem.A, q=problem.q, sqrt_w=sqrt_wq, used=problem.used,
        exact_columns=problem.exact_columns, row_cov=Sig,
    )
    scr = screen(base, rank_rtol)
    work = scr.work
    Sig_w = work.row_cov if work.row_cov is not None else Sig
    used_f = work.used.astype(np.float64)
    S = _scatter(problem)
    SSS = np.einsum("ia,tnab,jb->tnij", S, Sig_w[:, :, :-1, :-1], S)
    return scr, (work.A, work.q, used_f, Sig_w, S, SSS), var_q, sqrt_wq


def _starting_points(
    problem: Problem, scr: Screen, args: tuple[NDArray[np.float64], ...], gap_rtol: float, vm_tol: float
) -> tuple[NDArray[np.float64], NDArray[np.str_]]:
    """WLS with ``1 / var(q_i)``, or MTLS with the same row weights where its misfit is lower."""
    work = scr.work
    T = problem.shape[0]
    gain_ls, _ = ls_gain(work.Aw)
    x_wls = np.einsum("tmn,tn->tm", gain_ls, work.qw)
    F_wls = _grad_hess(x_wls, *args)[0]
    x0, start = x_wls, np.full(T, "wls", dtype="<U4")
    if len(problem.noisy_columns) > 0:
        x_mtls, _, _, ng = mtls_core(work.Aw, work.qw, problem.exact_columns, scr.ok, gap_rtol, vm_tol)
        F_mtls = _grad_hess(x_mtls, *args)[0]
        better = scr.ok & ~ng & (F_mtls < F_wls)
        x0 = np.where(better[:, None], x_mtls, x_wls)
        start = np.where(better, "mtls", start)
    return x0, start


def _noise_gain(
    x: NDArray[np.float64], args: tuple[NDArray[np.float64], ...], ok: NDArray[np.bool_]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Misfit, gradient, raw gain ``dx/dq`` ``(T, m, n)`` by implicit differentiation, and where the Hessian is PD."""
    F, grad, H, B = _grad_hess(x, *args)
    eye = np.eye(x.shape[1])
    h_min = np.linalg.eigvalsh(H)[:, 0]
    h_scale = np.abs(np.diagonal(H, axis1=1, axis2=2)).max(axis=1)
    pd = h_min > 1e-12 * np.maximum(h_scale, 1e-300)
    H_safe = np.where((ok & pd)[:, None, None], H, eye)
    J = -np.linalg.solve(H_safe, B)  # raw dx/dq, (T, m, n)
    return F, grad, J, pd
