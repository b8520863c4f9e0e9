"""Total least squares (TLS), stacked over epochs, and the gain of the TLS family.

Notes
-----
TLS solves ``min ||[ΔA Δq]||_F`` subject to ``(A + ΔA) x = q + Δq`` (Golub & Van Loan).
With ``C = [A q] = U S Vᵀ`` and ``v`` the right singular vector of the smallest singular
value ``σ_{m+1}``::

    x = −v[0:m] / v[m]  =  (AᵀA − σ²_{m+1} I)⁻¹ Aᵀ q

The SVD is taken of the ``(m+1) x (m+1)`` R factor of a stacked QR of ``C`` (same singular
values and right vectors). The problem is *nongeneric* — reported as
``Status.NONGENERIC`` with ``x = NaN`` — when ``|v[m]| <= vm_tol`` or when the gap
``σ_m(A) − σ_{m+1}(C) <= gap_rtol · σ_1(C)`` (then the solution is not unique or does not
exist).

The TLS family (TLS, DLS, MTLS) minimizes a misfit ratio
``f(x, q) = ||A x − q||² / (c0 + xᵀ D x)`` with ``D`` diagonal 0/1:
TLS ``(c0, D) = (1, I)``, MTLS ``(1, diag(noisy columns))``, DLS ``(0, I)``, LS ``(1, 0)``.
Implicit differentiation of the stationarity condition ``Aᵀ r ψ = ‖r‖² D x``
(``r = A x − q``, ``ψ = c0 + xᵀDx``, ``s² = f``) gives the exact noise gain
(:func:`misfit_ratio_gain`)::

    J = dx/dq = (AᵀA − s² D)⁻¹ (Aᵀ − 2 D x rᵀ / ψ)

Holding ``s`` fixed drops the second term; for TLS this is the paper's
``J Jᵀ = (AᵀA − s²I)⁻¹ AᵀA (AᵀA − s²I)⁻¹`` (:func:`gnss_cli.solvers.dop.tls_paper_cov`).
The two gains differ, but their products ``J Jᵀ`` coincide: expanding the exact one, the
cross terms ``−2(Aᵀr xᵀ + x rᵀA)/ψ = −4 s² D x xᵀ D/ψ`` (using ``Aᵀr = s² D x``) cancel the
quadratic term ``4 ||r||² D x xᵀ D/ψ²``. So the unweighted ``cov`` of TLS equals the paper's
formula (the tests check it; for WTLS the same holds on the whitened system); the
difference shows only in ``gain`` and in ``J Σ Jᵀ`` for a noise covariance ``Σ`` other
than the one the weights whiten.

References
----------
G. H. Golub and C. F. Van Loan, "An analysis of the total least squares problem",
SIAM J. Numer. Anal. 17 (1980). S. Van Huffel and J. Vandewalle, *The Total Least
Squares Problem*, SIAM (1991).

Examples
--------
>>> import numpy as np
>>> from gnss_cli.solvers import solve
>>> A = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, -1.0]])
>>> res = solve("tls", A, A @ np.array([0.5, 2.0]))
>>> res.status.name, np.round(res.x, 12).tolist()
('CONVERGED', [0.5, 2.0])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnss_cli.solvers.problem import DEFAULT_RANK_RTOL, Problem, finish_batch, screen
from gnss_cli.solvers.result import BatchResult, Status

__all__ = [
    "TlsDetails",
    "solve_tls_batch",
    "tls_core",
    "misfit_ratio_gain",
    "augmented_r",
    "DEFAULT_GAP_RTOL",
    "DEFAULT_VM_TOL",
]

DEFAULT_GAP_RTOL = 1e-10
"""Singular-value gaps below ``gap_rtol · σ_1`` make a TLS-type problem nongeneric."""

DEFAULT_VM_TOL = 1e-12
"""``|v[m]|`` below this makes a TLS problem nongeneric."""


@dataclass(frozen=True, slots=True)
class TlsDetails:
    """TLS-specific results (arrays over epochs; scalars in a :class:`SolveResult`).

    Attributes
    ----------
    sigma_min : ndarray, shape (T,)
        Smallest singular value of the (weighted) ``[A q]``; ``σ² = ||[ΔA Δq]||²_F``.
    sigma_min_A : ndarray, shape (T,)
        Smallest singular value of the (weighted) ``A``.
    cov_paper : ndarray, shape (T, m, m)
        The paper's ``(AᵀA − σ²I)⁻¹ AᵀA (AᵀA − σ²I)⁻¹`` (σ held fixed), for ``gdop_paper``.
    """

    sigma_min: NDArray[np.float64]
    sigma_min_A: NDArray[np.float64]
    cov_paper: NDArray[np.float64]


def augmented_r(C: NDArray[np.float64]) -> NDArray[np.float64]:
    """Square R factor ``(T, k, k)`` of stacked ``C (T, n, k)``, zero-padded when ``n < k``."""
    T, n, k = C.shape
    R = np.linalg.qr(C, mode="r")
    if R.shape[1] < k:
        R = np.concatenate([R, np.zeros((T, k - R.shape[1], k))], axis=1)
    return R


def misfit_ratio_gain(
    Aw: NDArray[np.float64],
    r: NDArray[np.float64],
    x: NDArray[np.float64],
    s2: NDArray[np.float64],
    d: NDArray[np.float64],
    c0: float,
    ok: NDArray[np.bool_],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Exact noise gain of the misfit-ratio estimators (TLS, DLS, MTLS).

    Parameters
    ----------
    Aw : ndarray, shape (T, n, m)
        Whitened design matrices (full column rank where ``ok``).
    r : ndarray, shape (T, n)
        Whitened residuals ``Aw x − qw`` at the solution.
    x : ndarray, shape (T, m)
        The solution.
    s2 : ndarray, shape (T,)
        The minimized misfit ``s² = ||r||² / ψ``.
    d : ndarray, shape (m,)
        Diagonal of ``D`` (1 = noisy column, 0 = exact column).
    c0 : float
        1 for TLS/MTLS, 0 for DLS.
    ok : ndarray of bool, shape (T,)
        Epochs to compute; others get an identity stand-in (their output is meaningless).

    Returns
    -------
    gain_w : ndarray, shape (T, m, n)
        ``(AᵀA − s²D)⁻¹ (Aᵀ − 2 D x rᵀ/ψ)`` with respect to the whitened ``qw``.
    p : ndarray, shape (T, m, m)
        ``R⁻¹ K⁻¹`` with ``(AᵀA − s²D)⁻¹ = p R⁻ᵀ`` and ``p pᵀ`` the fixed-``s`` gain
        ``(AᵀA − s²D)⁻¹ AᵀA (AᵀA − s²D)⁻¹``.
    k_min : ndarray, shape (T,)
        Smallest eigenvalue of ``K = I − s² R⁻ᵀ D R⁻¹``; ``AᵀA − s²D`` is positive
        definite iff ``k_min > 0``.

    Notes
    -----
    ``AᵀA`` is never formed: with ``Aw = Q R``, ``AᵀA − s²D = Rᵀ K R`` and
    ``J = R⁻¹ K⁻¹ (Qᵀ − R⁻ᵀ 2 D x rᵀ / ψ)``.
    """
    T, n, m = Aw.shape
    eye = np.eye(m)
    Q, R = np.linalg.qr(Aw, mode="reduced")
    R = np.where(ok[:, None, None], R, eye)
    r_inv = np.linalg.solve(R, np.broadcast_to(eye, R.shape))
    r_inv_t = np.swapaxes(r_inv, -1, -2)
    K = eye - s2[:, None, None] * (r_inv_t @ (d[None, :, None] * r_inv))
    K = 0.5 * (K + np.swapaxes(K, -1, -2))
    k_min = np.linalg.eigvalsh(K)[:, 0]
    K = np.where((ok & (k_min > 0))[:, None, None], K, eye)
    p = r_inv @ np.linalg.solve(K, np.broadcast_to(eye, K.shape))
    dx = d[None, :] * x
    psi = c0 + np.sum(dx * x, axis=1)
    psi = np.where(psi > 0, psi, 1.0)
    corr = np.einsum("tij,tj,tn->tin", r_inv_t, 2.0 * dx / psi[:, None], r)
    gain_w = p @ (np.swapaxes(Q, -1, -2) - corr)
    return gain_w, p, k_min


def tls_core(
    Aw: NDArray[np.float64],
    qw: NDArray[np.float64],
    sv_A: NDArray[np.float64],
    ok: NDArray[np.bool_],
    gap_rtol: float,
    vm_tol: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """TLS solution and exact gain of whitened stacked systems.

    Parameters
    ----------
    Aw : ndarray, shape (T, n, m)
    qw : ndarray, shape (T, n)
    sv_A : ndarray, shape (T, m)
        Singular values of ``Aw`` (descending).
    ok : ndarray of bool, shape (T,)
        Epochs that passed the rank screen.
    gap_rtol, vm_tol : float
        Nongeneric thresholds (see module notes).

    Returns
    -------
    x : (T, m)
    gain_w : (T, m, n)
    sigma_min : (T,)
        Smallest singular value of ``[Aw qw]``.
    cov_paper : (T, m, m)
    nongeneric : (T,) bool
    """
    T, n, m = Aw.shape
    C = np.concatenate([Aw, qw[:, :, None]], axis=2)
    Rc = augmented_r(C)
    _, s, vh = np.linalg.svd(Rc)
    v = vh[:, -1, :]
    sigma = s[:, -1]
    vm = v[:, m]
    gap = sv_A[:, -1] - sigma
    nongeneric = ok & ((np.abs(vm) <= vm_tol) | (gap <= gap_rtol * s[:, 0]))
    good = ok & ~nongeneric
    x = -v[:, :m] / np.where(good, vm, 1.0)[:, None]
    x = np.where(good[:, None], x, 0.0)
    r = np.einsum("tnm,tm->tn", Aw, x) - qw
    s2 = sigma * sigma
    gain_w, p, k_min = misfit_ratio_gain(Aw, r, x, s2, np.ones(m), 1.0, good)
    nongeneric |= good & (k_min <= 0)
    cov_paper = p @ np.swapaxes(p, -1, -2)
    return x, gain_w, sigma, cov_paper, nongeneric


def solve_tls_batch(
    problem: Problem,
    *,
    rank_rtol: float = DEFAULT_RANK_RTOL,
    gap_rtol: float = DEFAULT_GAP_RTOL,
    vm_tol: float = DEFAULT_VM_TOL,
) -> BatchResult:
    """Total least squares for every epoch (unweighted; see ``wtls`` for weights).

    Parameters
    ----------
    problem : Problem
    rank_rtol : float, optional
        Rank threshold for ``A`` (default 1e-12).
    gap_rtol : float, optional
        Relative gap ``σ_m(A) − σ_{m+1}([A q])`` below which the problem is nongeneric
        (default 1e-10).
    vm_tol : float, optional
        Threshold on ``|v[m]|`` (default 1e-12).

    Returns
    -------
    BatchResult
        ``cost = σ²_{m+1} = ||[ΔA Δq]||²_F``; ``details`` is a :class:`TlsDetails`.
    """
    return tls_batch("tls", problem, rank_rtol, gap_rtol, vm_tol)


def tls_batch(
    method: str,
    problem: Problem,
    rank_rtol: float,
    gap_rtol: float,
    vm_tol: float,
    column_scale: NDArray[np.float64] | None = None,
) -> BatchResult:
    """Shared TLS / WTLS driver; ``column_scale`` (m+1,) scales ``[A q]`` column-wise."""
    scr = screen(problem, rank_rtol)
    work = scr.work
    Aw, qw = work.Aw, work.qw
    sv_A = scr.sv
    if column_scale is not None:
        Aw = Aw * column_scale[None, None, :-1]
        qw = qw * column_scale[-1]
        sv_A = np.linalg.svd(augmented_r(Aw), compute_uv=False)
    x, gain_w, sigma, cov_paper, nongeneric = tls_core(Aw, qw, sv_A, scr.ok, gap_rtol, vm_tol)
    if column_scale is not None:
        d_a = column_scale[:-1]
        x = x * d_a[None, :] / column_scale[-1]
        gain_w = gain_w * d_a[None, :, None]
        cov_paper = cov_paper * (d_a[:, None] * d_a[None, :])[None]
    status = scr.status.copy()
    status[nongeneric] = Status.NONGENERIC
    bad = status < 0
    details = TlsDetails(
        sigma_min=np.where(scr.ok, sigma, np.nan),
        sigma_min_A=np.where(scr.ok, sv_A[:, -1], np.nan),
        cov_paper=np.where(bad[:, None, None], np.nan, cov_paper),
    )
    return finish_batch(method, problem, scr, x=x, gain_w=gain_w, cost=sigma * sigma, status=status, details=details)
