"""The paper's STLS GDOP: its TLS GDOP formula carried over to the block-Hankel matrix ``H_{l+1}(w)``.

What the paper writes (section 3, as far as the transcription in ``seed/`` keeps it)
------------------------------------------------------------------------------------
For one epoch the paper solves TLS on ``[H' q] = U S V^T`` and gives

    p_TLS  = (H'^T H' - s_5^2 I)^-1 H'^T q,
    GDOP_TLS = trace( (H'^T H' - s_5^2 I)^-1 H'^T H' (H'^T H' - s_5^2 I)^-1 )

(``s_5`` the smallest singular value of the augmented matrix; the square root is implied by
the name GDOP). For STLS it writes the kernel constraint ``[X^T -I] H_{l+1}(w) = 0`` (its
eq. 6), says that the solution ``[X; -I]`` is "similar" to the TLS solution but a matrix rather
than a vector because ``H_{l+1}(w)`` is ``q(l+1) x (T-l)``, and then: "with the above identity in
hand, the GDOP for the STLS problem can be easily computed as follows". Both the solution and
the GDOP survive only as token sequences: the solution as
``H(w) [I - H(w)^T (H(w) H(w)^T)^-1 H(w)]``-like and the GDOP as
``trace( ( H^T [I - H (H^T H)^-1 H^T] H )^-1 )``-like, six ``H_{l+1}(w)``, one ``I``, three
transposes; every subscript that would tell the blocks apart and every ``-1`` were lost.

Why it has to be reconstructed
------------------------------
Read literally, with the same ``H = H_{l+1}(w)`` everywhere, the bracket is the projector on the
complement of ``H``'s column (row) space, so ``H^T [I - H (H^T H)^-1 H^T] H = 0`` identically and
its inverse does not exist, whatever the data. The six matrices must therefore be *blocks* of
``H_{l+1}(w)``, and the only partition the paper's own constraint (eq. 6) uses is

    H_{l+1}(w) = [H_p; H_f],   H_p: the first rows (past samples), H_f: the last ``n_f`` rows,
    [X^T -I] H = 0   <=>   X^T H_p = H_f   <=>   H_p^T X = H_f^T,

which is the TLS problem ``A x = b`` of the paper's section 3 with ``A = H_p^T`` and ``b = H_f^T``
(``n_f`` right-hand sides). The paper's pointer to the TLS formula then fixes the rest.

The reconstruction implemented here
-----------------------------------
With ``M = H_p H_p^T`` and ``s`` the smallest singular value of the structured matrix
``H_{l+1}(w)`` (the analogue of ``s_5`` of ``[H' q]``):

    X      = (M - s^2 I)^-1 H_p H_f^T                       (TLS-type kernel parameter)
    Q      = (M - s^2 I)^-1  M  (M - s^2 I)^-1              (J J^T, J = dX[:, j]/dH_f[j, :] at fixed s)
    GDOP_STLS = sqrt(trace Q)

``Q`` is the same for each of the ``n_f`` columns of ``X``; the trace is of one column's
``Q`` as the paper's TLS trace is of ``p``'s. Properties (the tests check each one against a
direct computation):

- on a one-epoch system ``H = [H' q]^T`` (``n_f = 1``) it *is* the paper's TLS GDOP;
- for exact data (``s = 0``: ``w`` lies in a lag-``l`` behavior) it is the least-squares gain
  ``sqrt(trace (H_p H_p^T)^-1)``, the analogue of the paper's ``GDOP_LS``;
- ``X`` is the exact TLS kernel of ``H`` when ``n_f = 1`` (``-V[:-1, -1] / V[-1, -1]``).

What it is not
--------------
It is the noise gain of the *identified kernel parameters* from the trajectory, not of a
position from pseudoranges: no satellite geometry enters it. Its unit is the inverse of the
unit of ``w`` (1/m for positions in metres) and scales as ``1 / c`` when ``w`` is scaled by ``c``.
Its size is set by the smallest singular values of ``H_p``, which the fixes' noise dominates on
smooth trajectories: a mean of 0.68 1/m on the simulated 10 min flight of
``benchmarks/paper_kinematic.py``, 0.35 1/m on the static sample of ``sample_rinex/static``. It
is *not* comparable with the geometry DOP columns. The geometry DOP of a multi-epoch row is
``gdop`` (:mod:`gnss_cli.pipeline.multi_epoch_dop`).

Structured forms used by the ``stls --lag L`` rows (:func:`paper_stls_hankel`):

- ``full`` kernel: ``H = H_{l+1}(w)`` of the window's ENU fixes, ``n_f = q = 3`` (its value
  depends on the ENU origin, as the full kernel's fit does);
- ``shared`` kernel ``r(z) I_q`` with the fixed root at ``z = 1`` (the pipeline's):
  ``r(z) = (z - 1) r~(z)`` with ``r~`` monic of degree ``l - 1`` acting on the differences
  ``v(t) = w(t+1) - w(t)``; ``H = [H_l(v_1) H_l(v_2) ... H_l(v_q)]`` (each coordinate's scalar
  Hankel side by side: one recurrence for all), ``n_f = 1``. Independent of the origin. With
  ``l = 1`` nothing is identified and there is no STLS GDOP.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnss_cli.behavior.hankel import as_series, hankel
from gnss_cli.errors import NoSolutionError, UsageError

__all__ = ["PaperStlsGdop", "DegeneratePaperGdopError", "paper_stls_gdop", "paper_stls_hankel", "DEFAULT_GAP_RTOL"]

F64 = NDArray[np.float64]

DEFAULT_GAP_RTOL = 1e-10
"""``s_min(H_p) - s_min(H)`` at or below ``gap_rtol * s_max(H)`` is nongeneric (as for TLS)."""


class DegeneratePaperGdopError(NoSolutionError, ArithmeticError):
    """The paper's STLS GDOP does not exist for this matrix: ``H_p H_p^T - s^2 I`` is singular or
    indefinite (nongeneric, as TLS with ``s_min(A) <= s_min([A b])``), or nothing is identified."""


@dataclass(frozen=True, slots=True)
class PaperStlsGdop:
    """The paper's STLS GDOP of one structured matrix.

    Attributes
    ----------
    gdop : float
        ``sqrt(trace Q)``, unit: 1 / unit of ``H`` (1/m for positions in metres).
    cov : ndarray, shape (n_p, n_p)
        ``Q = (M - s^2 I)^-1 M (M - s^2 I)^-1``, ``M = H_p H_p^T``.
    x : ndarray, shape (n_p, n_f)
        The TLS-type kernel parameter ``X = (M - s^2 I)^-1 H_p H_f^T`` (``[X^T -I] H ~ 0``).
    sigma : float
        ``s``, the smallest singular value of ``H`` (0 when ``H`` has fewer columns than rows).
    sigma_min_past : float
        Smallest singular value of ``H_p``; the formula needs ``sigma_min_past > sigma``.
    cond : float
        Condition number of ``M - s^2 I``: ``(s_1(H_p)^2 - s^2) / (s_min(H_p)^2 - s^2)``.
    """

    gdop: float
    cov: F64
    x: F64
    sigma: float
    sigma_min_past: float
    cond: float


def paper_stls_gdop(h: ArrayLike, n_future: int, *, gap_rtol: float = DEFAULT_GAP_RTOL) -> PaperStlsGdop:
    """The paper's STLS GDOP of a structured matrix (module docstring: paper vs reconstruction).

    Parameters
    ----------
    h : array_like, shape (n_p + n_f, K)
        The structured matrix, e.g. ``H_{l+1}(w)`` (:func:`paper_stls_hankel`); its last
        ``n_future`` rows are ``H_f``. Any unit; the GDOP has the inverse unit.
    n_future : int
        ``n_f``, rows normalized to ``-I`` in the kernel ``[X^T -I]``, ``1 <= n_f < rows``.
    gap_rtol : float
        Nongeneric when ``s_min(H_p) - s <= gap_rtol * s_max(H)`` (default 1e-10).

    Returns
    -------
    PaperStlsGdop

    Raises
    ------
    UsageError
        ``h`` not a finite 2-D array, ``n_future`` out of range, or fewer columns than
        ``H_p`` has rows (``H_p H_p^T`` is then singular for any data).
    DegeneratePaperGdopError
        ``H`` is zero, or ``M - s^2 I`` is not positive definite (nongeneric).

    Notes
    -----
    Computed from the SVD ``H_p = U diag(d) V^T``: ``Q = U diag(d^2 / (d^2 - s^2)^2) U^T``
    (no inverse of a normal matrix is formed). ``J = (M - s^2 I)^-1 H_p`` is the gain of each
    column of ``X`` with respect to the matching row of ``H_f`` with ``s`` held fixed, so
    ``Q = J J^T``, as the paper's TLS formula is for ``p`` and ``q``.

    Examples
    --------
    >>> import numpy as np
    >>> A = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]); q = np.array([1.0, 2.0, 3.1])
    >>> g = paper_stls_gdop(np.column_stack([A, q]).T, 1)
    >>> s = np.linalg.svd(np.column_stack([A, q]), compute_uv=False)[-1]
    >>> K = np.linalg.inv(A.T @ A - s**2 * np.eye(2))
    >>> bool(np.isclose(g.gdop, np.sqrt(np.trace(K @ A.T @ A @ K))))
    True
    """
    H = np.asarray(h, dtype=np.float64)
    if H.ndim != 2 or H.size == 0:
        raise UsageError(f"paper_stls_gdop: 'h' must be a non-empty 2-D array; received shape {np.shape(h)}")
    if not np.all(np.isfinite(H)):
        raise UsageError(f"paper_stls_gdop: 'h' must be finite; received {int(np.count_nonzero(~np.isfinite(H)))} "
                         "non-finite entries")
    rows, cols = H.shape
    if isinstance(n_future, bool) or not isinstance(n_future, (int, np.integer)) or not 1 <= n_future < rows:
        raise UsageError(f"paper_stls_gdop: 'n_future' must be an integer in [1, {rows - 1}]; received {n_future!r}")
    n_p = rows - int(n_future)
    if cols < n_p:
        raise UsageError(f"paper_stls_gdop: 'h' needs at least {n_p} columns (rows of H_p) for H_p H_p^T to be "
                         f"invertible; received {cols}")
    s_all = np.linalg.svd(H, compute_uv=False)
    if s_all[0] == 0.0:
        raise DegeneratePaperGdopError("paper_stls_gdop: 'h' is zero; the kernel is not determined")
    sigma = float(s_all[-1]) if cols >= rows else 0.0
    u, d, _ = np.linalg.svd(H[:n_p], full_matrices=False)
    gap = d - sigma
    if not gap[-1] > gap_rtol * s_all[0]:
        raise DegeneratePaperGdopError(
            f"paper_stls_gdop: nongeneric: s_min(H_p) = {d[-1]:.6g} is not above s_min(H) = {sigma:.6g} "
            f"(relative gap {gap[-1] / s_all[0]:.3g} <= {gap_rtol:g}); H_p H_p^T - s^2 I is not positive definite")
    k = d**2 - sigma**2
    cov = (u * (d**2 / k**2)) @ u.T
    x = (u / k) @ (u.T @ (H[:n_p] @ H[n_p:].T))
    return PaperStlsGdop(gdop=float(np.sqrt(np.sum(d**2 / k**2))), cov=0.5 * (cov + cov.T), x=x, sigma=sigma,
                         sigma_min_past=float(d[-1]), cond=float(k[0] / k[-1]))


def paper_stls_hankel(w: ArrayLike, lag: int, structure: str = "shared", *, unit_root: bool = True) -> tuple[F64, int]:
    """The structured matrix and ``n_f`` of the paper's STLS GDOP for a kernel class of lag ``lag``.

    Parameters
    ----------
    w : array_like, shape (T, q)
        The trajectory (the data of the identification), e.g. a window's ENU fixes, m.
    lag : int
        ``l >= 1``.
    structure : {"shared", "full"}
        ``full``: ``H_{l+1}(w)``, ``n_f = q``. ``shared``: ``r(z) I_q``; the coordinates'
        scalar Hankel matrices side by side, ``n_f = 1``.
    unit_root : bool
        Shared only: the kernel keeps a fixed root at ``z = 1`` (the pipeline's), so the free
        part ``r~`` of degree ``l - 1`` acts on the differences ``w(t+1) - w(t)``.

    Returns
    -------
    h : ndarray
        ``(q (l+1), T - l)`` (full), ``(d + 1, q (T - d))`` (shared, ``d`` the free degree:
        ``l - 1`` with ``unit_root``, else ``l``).
    n_future : int

    Raises
    ------
    UsageError
        Bad ``w``, ``lag`` or ``structure``; too few samples for ``lag``.
    DegeneratePaperGdopError
        Shared with ``unit_root`` and ``lag = 1``: the kernel ``(z - 1) I`` is fixed, nothing is
        identified.
    """
    series = as_series(w)
    if isinstance(lag, bool) or not isinstance(lag, (int, np.integer)) or lag < 1:
        raise UsageError(f"paper_stls_hankel: 'lag' must be an integer >= 1; received {lag!r}")
    if structure not in ("shared", "full"):
        raise UsageError(f"paper_stls_hankel: 'structure' must be 'shared' or 'full'; received {structure!r}")
    if structure == "full":
        if series.shape[0] < lag + 1:
            raise UsageError(f"paper_stls_hankel: need at least {lag + 1} samples for lag {lag}; "
                             f"received {series.shape[0]}")
        return hankel(series, lag + 1), series.shape[1]
    data, degree = (np.diff(series, axis=0), lag - 1) if unit_root else (series, lag)
    if degree < 1:
        raise DegeneratePaperGdopError("paper_stls_hankel: the shared kernel of lag 1 with its fixed root at z = 1 "
                                       "is (z - 1) I: nothing is identified, there is no STLS GDOP")
    if data.shape[0] < degree + 1:
        raise UsageError(f"paper_stls_hankel: need at least {degree + 1 + int(unit_root)} samples for lag {lag}; "
                         f"received {series.shape[0]}")
    return np.hstack([hankel(data[:, c], degree + 1) for c in range(data.shape[1])]), 1
