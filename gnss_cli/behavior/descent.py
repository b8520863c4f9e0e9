"""The outer problem of the STLS: a damped Newton (Levenberg--Marquardt) descent over kernels.

The descent runs in the chart coordinates ``theta`` of :mod:`gnss_cli.behavior.chart` on the
whitened residual ``f(theta) = L^{-1} e`` of the inner problem (:mod:`gnss_cli.behavior.banded`).
Only steps that decrease the misfit are accepted; a rejected step raises the damping; when the
chart degenerates the descent re-charts. :func:`gnss_cli.behavior.stls.stls` chooses the starts
(:mod:`gnss_cli.behavior.starts`) and keeps the best descent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior.banded import BandedGram, InnerProblem, SingularGramError, solve_lower
from gnss_cli.behavior.chart import FullChart, SharedChart
from gnss_cli.behavior.hankel import hankel_rows
from gnss_cli.behavior.kernel import KernelRepresentation
from gnss_cli.behavior.result import StlsStatus

__all__ = ["Descent", "minimize", "final_kernel", "MU_INITIAL", "MU_REJECTED"]

#: Initial Levenberg--Marquardt damping, relative to the diagonal of the curvature. The misfit
#: curvature is ill-conditioned (the Hankel data excite some kernel directions far more than
#: others), so a large initial damping would hold back the weak directions for many iterations.
MU_INITIAL = 1e-8
#: Damping after a rejected step (at least): a step that failed with almost no damping is
#: rejected again after a mere doubling, so the damping jumps to where it shortens the step.
MU_REJECTED = 1e-3


@dataclass(slots=True)
class Descent:
    """The end of one descent: chart, coordinates, projection, status and counters."""

    chart: FullChart | SharedChart
    theta: NDArray[np.float64]
    state: BandedGram
    status: StlsStatus
    iterations: int
    n_eval: int
    grad_norm: float


def _derivatives(
    problem: InnerProblem, chart: FullChart | SharedChart, theta: NDArray[np.float64], state: BandedGram,
    hessian: str,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | None]:
    """Half gradient ``J^T f``, half Hessian and (exact mode) Gauss--Newton matrix in chart coordinates.

    With ``lambda = Gamma^{-1} e``, ``u_k = (dG/dtheta_k)^T lambda`` and
    ``c_k = (dG/dtheta_k) w_hat - G Sigma u_k`` the exact half Hessian is
    ``a_k^T a_m - u_k^T Sigma u_m`` with ``a_k = L^{-1} c_k``; Gauss--Newton keeps ``J^T J``.
    """
    d_mat = chart.jacobian_rhs(state.w_hat)
    jac = solve_lower(state.chol, d_mat)
    grad = jac.T @ state.f
    gn_mat = jac.T @ jac
    if hessian == "gauss-newton":
        return grad, gn_mat, None
    basis = chart.basis_blocks()  # (n_p, l+1, g, q)
    n_p, n_blk, g, q = basis.shape
    lam = state.lam
    n = lam.shape[0]
    n_t = n + n_blk - 1
    big = (lam @ basis.transpose(2, 1, 3, 0).reshape(g, n_blk * q * n_p)).reshape(n, n_blk, q, n_p)
    u = np.zeros((n_t, q, n_p))
    for i in range(n_blk):
        u[i : i + n] += big[:, i]
    s = problem.cov.apply_batch(u)
    r_mat = chart.blocks(theta).transpose(1, 0, 2).reshape(g, n_blk * q)
    s_rows = hankel_rows(s.reshape(n_t, q * n_p), n_blk).reshape(n, n_blk * q, n_p)
    gs = r_mat @ s_rows  # (n, g, n_p): G Sigma u_k
    a = solve_lower(state.chol, d_mat - gs.reshape(n * g, n_p))
    hess = a.T @ a - u.reshape(n_t * q, n_p).T @ s.reshape(n_t * q, n_p)
    return grad, 0.5 * (hess + hess.T), gn_mat


def _cholesky_solve(a_mat: NDArray[np.float64], rhs: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """``a_mat^{-1} rhs`` for a symmetric positive definite ``a_mat``; None when the Cholesky factorization fails."""
    from scipy.linalg import lapack  # scipy.linalg: imported by the multi-epoch methods only

    fac, info = lapack.dpotrf(a_mat, lower=1)
    if info != 0:
        return None
    x, info = lapack.dpotrs(fac, rhs, lower=1)
    return x if info == 0 else None


def minimize(
    problem: InnerProblem, chart: FullChart | SharedChart, theta: NDArray[np.float64], state: BandedGram,
    fixed: NDArray[np.float64], q: int, tol: float, max_iter: int, rechart_threshold: float, hessian: str,
    exact_level: float,
) -> Descent:
    """Damped Newton / Levenberg--Marquardt descent from ``theta`` (only decreasing steps accepted).

    With the exact Hessian, an iteration where it is not positive definite (far from a
    minimum) takes the Gauss--Newton curvature instead.
    """
    status = StlsStatus.ITERATION_LIMIT
    iterations = 0
    n_eval = 0
    grad_norm = 0.0
    mu = MU_INITIAL
    nu = 2.0
    if chart.n_params == 0:
        status = StlsStatus.DIRECT
    while status == StlsStatus.ITERATION_LIMIT and iterations < max_iter:
        if state.misfit <= exact_level:
            status = StlsStatus.EXACT
            break
        grad, a_mat, gn_mat = _derivatives(problem, chart, theta, state, hessian)
        grad_norm = float(np.abs(grad).max())
        iterations += 1
        if grad_norm == 0.0:
            status = StlsStatus.CONVERGED
            break
        newton = _cholesky_solve(a_mat, grad)
        if newton is not None:  # Newton decrement: the predicted decrease of an undamped step
            if float(grad @ newton) <= 0.1 * tol * state.misfit:
                status = StlsStatus.CONVERGED
                break
        elif gn_mat is not None:
            a_mat = gn_mat
        diag = np.abs(a_mat.diagonal())
        diag = np.maximum(diag, 1e-12 * max(float(diag.max()), np.finfo(float).tiny))
        theta_norm = float(np.sqrt(theta @ theta))
        while True:
            damped = a_mat.copy()
            damped.flat[:: damped.shape[0] + 1] += mu * diag
            sol = _cholesky_solve(damped, grad)
            step = -sol if sol is not None else None
            finite = step is not None and bool(np.isfinite(step).all())
            predicted = float(-2.0 * grad @ step - step @ a_mat @ step) if finite and step is not None else -1.0
            trial: BandedGram | None = None
            if predicted > 0.0:
                try:
                    n_eval += 1
                    trial = problem.project(chart.blocks(theta + step))
                except SingularGramError:
                    trial = None
            if trial is not None and trial.misfit < state.misfit and step is not None:
                rho = (state.misfit - trial.misfit) / predicted
                mu *= max(1.0 / 10.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                decrease = state.misfit - trial.misfit
                theta = theta + step
                state = trial
                step_norm = float(np.sqrt(step @ step))
                small_step = step_norm <= tol * (float(np.sqrt(theta @ theta)) + tol)
                if (decrease <= tol * state.misfit and rho > 0.25) or small_step:
                    status = StlsStatus.CONVERGED
                elif chart.needs_rechart(theta, rechart_threshold):
                    chart, theta = _rechart(chart, theta, fixed, q)
                break
            mu = max(mu * nu, MU_REJECTED)
            nu *= 2.0
            if mu > 1e16 or (finite and step is not None
                             and float(np.sqrt(step @ step)) <= 1e-15 * (theta_norm + 1e-15)):
                status = StlsStatus.NO_FURTHER_DECREASE
                break
    if status == StlsStatus.ITERATION_LIMIT and state.misfit <= exact_level:
        status = StlsStatus.EXACT
    return Descent(chart, theta, state, status, iterations, n_eval, grad_norm)


def _rechart(chart: FullChart | SharedChart, theta: NDArray[np.float64], fixed: NDArray[np.float64],
             q: int) -> tuple[FullChart | SharedChart, NDArray[np.float64]]:
    """Move to the chart whose identity block (or pinned coefficient) is best conditioned."""
    if isinstance(chart, SharedChart):
        rt = chart.r_tilde(theta)
        new_s = SharedChart(fixed, rt, q)
        return new_s, new_s.coordinates_tilde(rt)
    r_mat = chart.kernel(theta)
    new_f = FullChart(r_mat, q)
    if np.array_equal(new_f.ident, chart.ident):
        return chart, theta
    try:
        return new_f, new_f.coordinates(r_mat)
    except np.linalg.LinAlgError:  # pragma: no cover - pivoted QR picks a regular block
        return chart, theta


def final_kernel(chart: FullChart | SharedChart, theta: NDArray[np.float64], q: int) -> KernelRepresentation:
    if isinstance(chart, SharedChart):
        r = chart.shared_r(theta)
        scale = r[-1] if abs(r[-1]) > 1e-8 * np.max(np.abs(r)) else np.linalg.norm(r)
        return KernelRepresentation.shared(r / scale, q)
    return KernelRepresentation(chart.kernel(theta), q=q).orthonormalized()
