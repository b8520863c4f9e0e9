"""Data least squares (DLS): errors in ``A`` only, ``q`` exact.

Notes
-----
DLS solves ``min ||ΔA||_F`` subject to ``(A + ΔA) x = q`` (DeGroat & Dowling). For a given
``x`` the smallest correction has ``||ΔA||_F = ||A x − q|| / ||x||``, so DLS minimizes the
misfit ratio ``||A x − q||² / xᵀx``. With ``P = I − q qᵀ/qᵀq`` and ``v`` the right
singular vector of ``P A`` for its smallest singular value ``σ``::

    x = (qᵀq / qᵀA v) · v,        ||ΔA||²_F = σ²

(DESIGN.md section 3). The right singular vectors come from the SVD of the R factor of a
stacked QR of ``P A``. Row weights whiten ``A`` and ``q`` first (``min ||W^{1/2} ΔA||_F``).
The problem is nongeneric when ``qᵀA v ≈ 0``, when ``σ`` is not simple, or when
``σ >= σ_min(A)`` (then ``AᵀA − σ²I`` is singular and the gain is undefined). A zero ``q``
over the used rows gives ``Status.DEGENERATE_DATA``.

The exact noise gain is that of the misfit ratio with ``(c0, D) = (0, I)``
(:func:`gnss_cli.solvers.tls.misfit_ratio_gain`):
``J = (AᵀA − σ²I)⁻¹ (Aᵀ − 2 x rᵀ / xᵀx)``.

References
----------
R. D. DeGroat and E. M. Dowling, "The data least squares problem and channel
equalization", IEEE Trans. Signal Processing 41 (1993).

Examples
--------
>>> import numpy as np
>>> from gnss_cli.solvers import solve
>>> A = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
>>> np.round(solve("dls", A, A @ np.array([2.0, 1.0])).x, 12).tolist()
[2.0, 1.0]
"""

from __future__ import annotations

import numpy as np

from gnss_cli.solvers.problem import DEFAULT_RANK_RTOL, Problem, finish_batch, screen
from gnss_cli.solvers.result import BatchResult, Status
from gnss_cli.solvers.tls import DEFAULT_GAP_RTOL, augmented_r, misfit_ratio_gain

__all__ = ["solve_dls_batch"]


def solve_dls_batch(
    problem: Problem,
    *,
    rank_rtol: float = DEFAULT_RANK_RTOL,
    gap_rtol: float = DEFAULT_GAP_RTOL,
) -> BatchResult:
    """Data least squares for every epoch.

    Parameters
    ----------
    problem : Problem
        Validated problem; weights (if any) whiten the rows.
    rank_rtol : float, optional
        Rank threshold for ``A`` (default 1e-12).
    gap_rtol : float, optional
        Relative singular-value gap below which the problem is nongeneric (default 1e-10).

    Returns
    -------
    BatchResult
        ``cost = σ² = min ||W^{1/2} ΔA||²_F``.
    """
    scr = screen(problem, rank_rtol)
    work = scr.work
    Aw, qw = work.Aw, work.qw
    T, n, m = Aw.shape
    qq = np.sum(qw * qw, axis=1)
    degenerate = scr.ok & (qq <= 0)
    ok = scr.ok & ~degenerate
    qq_safe = np.where(ok, qq, 1.0)
    qA = np.einsum("tn,tnm->tm", qw, Aw)
    PA = Aw - qw[:, :, None] * (qA / qq_safe[:, None])[:, None, :]
    _, s, vh = np.linalg.svd(augmented_r(PA))
    v = vh[:, -1, :]
    sigma = s[:, -1]
    qAv = np.sum(qA * v, axis=1)
    scale = np.sqrt(qq_safe) * scr.sv[:, 0]
    gap_simple = (s[:, -2] - sigma) if m > 1 else np.full(T, np.inf)
    nongeneric = ok & (
        (np.abs(qAv) <= gap_rtol * scale)
        | (gap_simple <= gap_rtol * s[:, 0])
        | (scr.sv[:, -1] - sigma <= gap_rtol * scr.sv[:, 0])
    )
    good = ok & ~nongeneric
    x = (qq_safe / np.where(good, qAv, 1.0))[:, None] * v
    x = np.where(good[:, None], x, 0.0)
    r = np.einsum("tnm,tm->tn", Aw, x) - qw
    gain_w, _, k_min = misfit_ratio_gain(Aw, r, x, sigma * sigma, np.ones(m), 0.0, good)
    nongeneric |= good & (k_min <= 0)
    status = scr.status.copy()
    status[nongeneric] = Status.NONGENERIC
    status[degenerate] = Status.DEGENERATE_DATA
    return finish_batch("dls", problem, scr, x=x, gain_w=gain_w, cost=sigma * sigma, status=status)
