"""Least squares over windows of epochs whose trajectory is constrained to a behavior (numerics only).

The measurement-domain multi-epoch problem of DESIGN.md section 6. Epoch ``t`` has linearized
rows ``y_t = P_t z_t + C_t b_t + noise`` (weights ``W_t``): ``z_t`` the unknown position minus
the linearization point (m), ``b_t`` the epoch's free nuisance columns (receiver clocks, one
per system; for range rates the clock drift) and ``C_t`` their 0/1 columns. Eliminating
``b_t`` leaves the clock-reduced normal equations of the epoch (:func:`reduce_epochs`)::

    M_t = P^T W P - P^T W C (C^T W C)^+ C^T W P,   r_t = P^T W y - P^T W C (C^T W C)^+ C^T W y,
    s_t = y^T W y - y^T W C (C^T W C)^+ C^T W y,

so that ``min_b |y - P z - C b|^2_W = s_t - 2 z^T r_t + z^T M_t z``. An epoch with fewer
satellites than position unknowns plus clocks has a singular ``M_t`` (one satellite: zero) and
still contributes what it has.

Over a window of ``N`` epochs the positions are ``x_t = origin + O_t theta`` (``O`` a basis of
the behavior, ``(N, 3, K)``) and, with range rates, the velocities ``v_t = V_t theta`` (``V`` the
time derivative of the basis, :func:`velocity_operator`). With ``a_t = origin - x_nom_t``
(``z_t = a_t + O_t theta``) the window's normal equations are::

    (sum_t O_t^T M_t O_t + V_t^T Md_t V_t) theta = sum_t O_t^T (r_t - M_t a_t) + V_t^T rd_t,

(:func:`solve_windows`, all windows at once), solved by Cholesky (``K`` is small: 3 lag). The
misfit of the solution is ``sum_t s_t - 2 z_t^T r_t + z_t^T M_t z_t`` (and the range-rate terms);
its degrees of freedom are the rows minus the clocks minus ``K``. The same epochs solved one at a
time with free positions (and free velocities) have the misfit of :func:`free_misfit`; the
difference tests the behavior (:mod:`gnss_cli.pipeline.window_solve`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["EpochNormals", "WindowSolution", "reduce_epochs", "velocity_operator", "solve_windows", "free_misfit"]

F64 = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class EpochNormals:
    """Clock-reduced normal equations of ``T`` epochs (module docstring).

    Attributes
    ----------
    M : ``(T, 3, 3)`` reduced information of the position (or velocity), 1/m^2.
    r : ``(T, 3)`` reduced right-hand side, 1/m.
    s : ``(T,)`` reduced weighted square sum of the rows, unitless.
    n_rows : ``(T,)`` rows with a positive weight.
    n_free : ``(T,)`` nuisance columns estimated (clocks with at least one row).
    """

    M: F64
    r: F64
    s: F64
    n_rows: NDArray[np.int64]
    n_free: NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class WindowSolution:
    """Solutions of ``B`` windows.

    Attributes
    ----------
    theta : ``(B, K)`` coefficients of the basis (NaN where the window's information is singular).
    misfit : ``(B,)`` weighted residual square sum at ``theta``.
    dof : ``(B,)`` rows minus nuisance columns minus ``K``.
    ok : ``(B,)`` the window's normal matrix was positive definite.
    """

    theta: F64
    misfit: F64
    dof: NDArray[np.int64]
    ok: NDArray[np.bool_]


def reduce_epochs(p: F64, weight: F64, y: F64, clock_cols: F64 | None = None) -> EpochNormals:
    """Eliminate each epoch's nuisance columns from its weighted rows.

    Parameters
    ----------
    p : ``(T, n, 3)``
        Rows' coefficients of the position (or velocity) correction.
    weight : ``(T, n)``
        Row weights, 1/m^2 (0 for rows not used).
    y : ``(T, n)``
        Right-hand sides, m (anything where the weight is 0).
    clock_cols : ``(T, n, k)``, optional
        0/1 nuisance columns (one per system); None: one column common to every row.

    Returns
    -------
    EpochNormals
    """
    c = np.ones((*weight.shape, 1)) if clock_cols is None else clock_cols
    used = weight > 0
    y = np.where(used, y, 0.0)
    p = np.where(used[..., None], p, 0.0)  # rows not used may hold NaN
    cw = c * weight[..., None]
    sw = cw.sum(axis=1)  # (T, k)
    inv = np.where(sw > 0, 1.0 / np.where(sw > 0, sw, 1.0), 0.0)
    g = np.einsum("tnk,tni->tki", cw, p)  # C^T W P
    cy = np.einsum("tnk,tn->tk", cw, y)  # C^T W y
    M = np.einsum("tni,tn,tnj->tij", p, weight, p) - np.einsum("tki,tk,tkj->tij", g, inv, g)
    r = np.einsum("tni,tn,tn->ti", p, weight, y) - np.einsum("tki,tk,tk->ti", g, inv, cy)
    s = np.einsum("tn,tn,tn->t", weight, y, y) - np.einsum("tk,tk,tk->t", cy, inv, cy)
    return EpochNormals(0.5 * (M + M.transpose(0, 2, 1)), r, s, (weight > 0).sum(axis=1), (sw > 0).sum(axis=1))


def velocity_operator(basis: F64, dt_s: float) -> F64:
    """Time derivative of a basis ``(..., N, 3, K)`` (m per unit of theta) by second-order differences, 1/s.

    Exact for trajectories that are quadratic in time (central differences inside, one-sided
    three-point differences at the ends).

    >>> t = np.arange(5.0)
    >>> O = np.stack([np.ones(5), t, t**2], axis=1)[:, None, :]  # (5, 1, 3)
    >>> velocity_operator(O, 0.5)[:, 0, 2].tolist()  # d(t^2)/d(time) = 2 t / 0.5
    [0.0, 4.0, 8.0, 12.0, 16.0]
    """
    n_t = basis.shape[-3]
    if n_t < 3:
        return np.gradient(basis, dt_s, axis=-3) if n_t == 2 else np.zeros_like(basis)
    return np.gradient(basis, dt_s, axis=-3, edge_order=2)


def _gather(normals: EpochNormals, spans: NDArray[np.intp]) -> tuple[F64, F64, F64]:
    return normals.M[spans], normals.r[spans], normals.s[spans]


def solve_windows(basis: F64, spans: NDArray[np.intp], offset: F64, pr: EpochNormals,
                  vel_op: F64 | None = None, rr: EpochNormals | None = None) -> WindowSolution:
    """Least-squares coefficients of ``B`` windows of ``N`` epochs (module docstring).

    Parameters
    ----------
    basis : ``(B, N, 3, K)``
        Behavior basis of each window, ECEF m per unit of theta.
    spans : ``(B, N)``
        Epoch indices of each window into the per-epoch normals.
    offset : ``(B, N, 3)``
        ``a_t = origin - x_nom_t``, m.
    pr : EpochNormals
        Pseudorange normals of every epoch (:func:`reduce_epochs` at ``x_nom``).
    vel_op : ``(B, N, 3, K)``, optional
        Velocity of the basis (:func:`velocity_operator`), m/s per unit of theta.
    rr : EpochNormals, optional
        Range-rate normals (absolute velocity, clock drift eliminated).

    Returns
    -------
    WindowSolution
    """
    M, r, s = _gather(pr, spans)
    mo = np.matmul(M, basis)
    A = np.einsum("btik,btil->bkl", basis, mo)
    rhs = np.einsum("btik,bti->bk", basis, r - np.einsum("btij,btj->bti", M, offset))
    rows = pr.n_rows[spans].sum(axis=1) - pr.n_free[spans].sum(axis=1)
    use_rr = vel_op is not None and rr is not None
    if use_rr:
        Md, rd, _ = _gather(rr, spans)
        A = A + np.einsum("btik,btil->bkl", vel_op, np.matmul(Md, vel_op))
        rhs = rhs + np.einsum("btik,bti->bk", vel_op, rd)
        rows = rows + rr.n_rows[spans].sum(axis=1) - rr.n_free[spans].sum(axis=1)
    A = 0.5 * (A + A.transpose(0, 2, 1))
    K = basis.shape[-1]
    theta = np.full((A.shape[0], K), np.nan)
    scale = np.sqrt(np.clip(np.einsum("bkk->bk", A), 1e-300, None))
    a_n = A / scale[:, :, None] / scale[:, None, :]  # unit diagonal: Cholesky sees the condition, not the units
    ok = np.zeros(A.shape[0], dtype=bool)
    for idx in _chunks_positive(a_n):
        chol = np.linalg.cholesky(a_n[idx])
        u = np.linalg.solve(chol, (rhs[idx] / scale[idx])[..., None])
        theta[idx] = np.linalg.solve(np.swapaxes(chol, -1, -2), u)[..., 0] / scale[idx]
        ok[idx] = True
    z = offset + np.einsum("btik,bk->bti", basis, np.nan_to_num(theta))
    mis = np.einsum("bt->b", s) - 2 * np.einsum("bti,bti->b", z, r) + np.einsum("bti,btij,btj->b", z, M, z)
    if use_rr:
        v = np.einsum("btik,bk->bti", vel_op, np.nan_to_num(theta))
        mis = mis + rr.s[spans].sum(axis=1) - 2 * np.einsum("bti,bti->b", v, rd) + np.einsum("bti,btij,btj->b", v, Md, v)
    return WindowSolution(theta, np.where(ok, mis, np.nan), (rows - K).astype(np.int64), ok)


def _chunks_positive(a_n: F64) -> list[NDArray[np.intp]]:
    """Indices of the matrices whose smallest eigenvalue exceeds 1e-12 (unit diagonal), as one group."""
    if a_n.shape[0] == 0:
        return []
    good = np.linalg.eigvalsh(a_n)[:, 0] > 1e-12
    return [np.flatnonzero(good)] if good.any() else []


def free_misfit(normals: EpochNormals, rcond: float = 1e-10) -> tuple[F64, NDArray[np.int64]]:
    """Misfit and rank of each epoch solved alone with a free position: ``s - r^T M^+ r``.

    Returns
    -------
    misfit : ``(T,)`` weighted residual square sum.
    rank : ``(T,)`` rank of ``M`` (position unknowns the epoch determines).
    """
    M_pinv = np.linalg.pinv(normals.M, rcond=rcond, hermitian=True)
    if normals.M.size:  # matrix_rank(M, rtol=rcond, hermitian=True), which numpy < 2 lacks
        s = np.abs(np.linalg.eigvalsh(normals.M))
        rank = np.sum(s > s.max(axis=-1, keepdims=True) * rcond, axis=-1)
    else:
        rank = np.zeros(0, np.int64)
    return normals.s - np.einsum("ti,tij,tj->t", normals.r, M_pinv, normals.r), np.asarray(rank, dtype=np.int64)
