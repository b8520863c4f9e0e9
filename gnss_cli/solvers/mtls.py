"""Mixed least squares – total least squares (MTLS): some columns of ``A`` are exact.

Notes
-----
With ``A = [A_E A_N]`` (exact and noisy columns) MTLS solves
``min ||[ΔA_N Δq]||_F`` subject to ``A_E x_E + (A_N + ΔA_N) x_N = q + Δq``
(Golub, Hoffman & Stewart 1987; Van Huffel & Vandewalle section 3.6.3). Algorithm
(DESIGN.md section 3): QR of ``[A_E A_N q] = Q R``, TLS on the trailing block
``R[m_E:, m_E:]`` (noisy columns and q, the part orthogonal to ``A_E``), then
back-substitution ``x_E = R_EE⁻¹ (r_Eq − R_EN x_N)``. Equivalently it minimizes the misfit
ratio ``||A x − q||² / (1 + ||x_N||²)``, whose exact noise gain is
``J = (AᵀA − σ² D)⁻¹ (Aᵀ − 2 D x rᵀ / (1 + ||x_N||²))``, ``D = diag(noisy columns)``
(:func:`gnss_cli.solvers.tls.misfit_ratio_gain`). With every column exact MTLS is LS, with
none it is TLS. Row weights whiten ``[A q]`` first.

Nongeneric (``Status.NONGENERIC``) when the last component of the trailing singular vector
is ~0 or the trailing block's noisy part has no gap to the smallest singular value.

Examples
--------
>>> import numpy as np
>>> from gnss_cli.solvers import solve
>>> A = np.column_stack([[1.0, 2.0, 3.0, 4.0], np.ones(4)])
>>> np.round(solve("mtls", A, A @ np.array([0.5, -1.0]), exact_columns=[1]).x, 12).tolist()
[0.5, -1.0]
"""

from __future__ import annotations

import numpy as np

from gnss_cli.solvers.problem import DEFAULT_RANK_RTOL, Problem, finish_batch, screen
from gnss_cli.solvers.result import BatchResult, Status
from gnss_cli.solvers.tls import DEFAULT_GAP_RTOL, DEFAULT_VM_TOL, augmented_r, misfit_ratio_gain

__all__ = ["solve_mtls_batch", "mtls_core"]


def mtls_core(
    Aw: np.ndarray,
    qw: np.ndarray,
    exact_columns: tuple[int, ...],
    ok: np.ndarray,
    gap_rtol: float,
    vm_tol: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """MTLS solution and exact gain of whitened stacked systems.

    Parameters
    ----------
    Aw : ndarray, shape (T, n, m)
    qw : ndarray, shape (T, n)
    exact_columns : tuple of int
    ok : ndarray of bool, shape (T,)
        Epochs that passed the rank screen.
    gap_rtol, vm_tol : float

    Returns
    -------
    x : (T, m)
    gain_w : (T, m, n)
    sigma : (T,)
        Smallest singular value of the trailing block (``σ² = ||[ΔA_N Δq]||²_F``).
    nongeneric : (T,) bool
    """
    T, n, m = Aw.shape
    noisy = [j for j in range(m) if j not in exact_columns]
    exact = list(exact_columns)
    m_e, m_n = len(exact), len(noisy)
    order = exact + noisy
    C = np.concatenate([Aw[:, :, order], qw[:, :, None]], axis=2)
    R = augmented_r(C)
    if m_n == 0:
        sigma = np.abs(R[:, m, m])
        xp_n = np.zeros((T, 0))
        nongeneric = np.zeros(T, dtype=bool)
    else:
        B = R[:, m_e:, m_e:]
        _, s, vh = np.linalg.svd(B)
        v = vh[:, -1, :]
        sigma = s[:, -1]
        vm = v[:, m_n]
        s_noisy = np.linalg.svd(R[:, m_e:m, m_e:m], compute_uv=False)[:, -1]
        nongeneric = ok & ((np.abs(vm) <= vm_tol) | (s_noisy - sigma <= gap_rtol * s[:, 0]))
        vm_safe = np.where(ok & ~nongeneric, vm, 1.0)
        xp_n = -v[:, :m_n] / vm_safe[:, None]
    good = ok & ~nongeneric
    if m_e:
        R_ee = np.where(good[:, None, None], R[:, :m_e, :m_e], np.eye(m_e))
        rhs = R[:, :m_e, m] - np.einsum("tij,tj->ti", R[:, :m_e, m_e:m], xp_n)
        xp_e = np.linalg.solve(R_ee, rhs[:, :, None])[:, :, 0]
    else:
        xp_e = np.zeros((T, 0))
    x = np.empty((T, m))
    x[:, order] = np.concatenate([xp_e, xp_n], axis=1)
    x = np.where(good[:, None], x, 0.0)
    d = np.zeros(m)
    d[noisy] = 1.0
    r = np.einsum("tnm,tm->tn", Aw, x) - qw
    gain_w, _, k_min = misfit_ratio_gain(Aw, r, x, sigma * sigma, d, 1.0, good)
    nongeneric = nongeneric | (good & (k_min <= 0))
    return x, gain_w, sigma, nongeneric


def solve_mtls_batch(
    problem: Problem,
    *,
    rank_rtol: float = DEFAULT_RANK_RTOL,
    gap_rtol: float = DEFAULT_GAP_RTOL,
    vm_tol: float = DEFAULT_VM_TOL,
) -> BatchResult:
    """Mixed LS–TLS for every epoch; ``problem.exact_columns`` are the exact columns.

    Parameters
    ----------
    problem : Problem
    rank_rtol, gap_rtol, vm_tol : float, optional
        As for :func:`gnss_cli.solvers.tls.solve_tls_batch`.

    Returns
    -------
    BatchResult
        ``cost = ||[ΔA_N Δq]||²_F`` (whitened).
    """
    scr = screen(problem, rank_rtol)
    work = scr.work
    x, gain_w, sigma, nongeneric = mtls_core(
        work.Aw, work.qw, problem.exact_columns, scr.ok, gap_rtol, vm_tol
    )
    status = scr.status.copy()
    status[nongeneric] = Status.NONGENERIC
    return finish_batch("mtls", problem, scr, x=x, gain_w=gain_w, cost=sigma * sigma, status=status)
