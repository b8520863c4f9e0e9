"""Linear Kalman filter and Rauch-Tung-Striebel smoother (matrices only, no GNSS).

Model, steps ``t = 0 .. T-1``::

    x_0 ~ N(m_0, P_0),    x_t = F_t x_{t-1} + w_t,  w_t ~ N(0, Q_t)   (t >= 1)
    y_t = H_t x_t + v_t,  v_t ~ N(0, diag(r_t))
    y'_t = H'_t x_t + G_t c_t + v'_t,  v'_t ~ N(0, diag(r'_t)),  c_t free (no prior)

Each step may have its own number of measurements (0 included). The rows with free nuisance
parameters ``c_t`` (:class:`FreeRows`) are eliminated exactly: whitened, they are projected onto
the orthogonal complement of the columns of ``G_t`` (an orthonormal basis ``Q2`` with
``Q2^T R^(-1/2) G_t = 0``), which leaves rows of unit variance free of ``c_t``. For any basis the
update with them equals the joint least squares over ``x_t`` and ``c_t``, so the RTS smoother
below needs no change. A measurement of the change between two steps (``x_t - x_{t-1}``) is made
a measurement of one state by stochastic cloning (:func:`clone_transition`): the state is
augmented with a copy of the previous state's chosen components; the augmented states are still
a Markov chain with the measurements of step ``t`` on state ``t`` alone, so filter and smoother
are exact for it (the tests check the smoother against the batch solution).

The filter's update is the Joseph form ``P+ = (I - K H) P- (I - K H)^T + K R K^T`` (symmetric
and positive semidefinite in floating point for any gain), with ``K = P- H^T S^-1``,
``S = H P- H^T + R`` (solved, not inverted). The RTS smoother runs backwards:
``C_t = P_t F_{t+1}^T (P-_{t+1})^-1``, ``x^s_t = x_t + C_t (x^s_{t+1} - x-_{t+1})``,
``P^s_t = P_t + C_t (P^s_{t+1} - P-_{t+1}) C_t^T``. For this linear-Gaussian model the
smoothed means are the batch MAP estimate (the minimiser of the stacked weighted least
squares over all states) and the smoothed covariances the matching blocks of the inverse of
its information matrix; the tests check both.

Gate (``gate``: a threshold on standardized statistics, N(0, 1) when the model holds). The rows
``H_t``: the innovation ``nu_i = y_i - H_i x-`` over ``sqrt(S_ii)``, against the prediction; a row
above the gate is not used unless more than half of the rows of its group (``groups``) are above
it (then the prior is what is wrong, e.g. a manoeuvre the motion model did not expect). The free
rows: the innovation of row ``i`` predicted from the prior *and the step's other free rows* over
its sigma (the w-test of the update's residuals: residual ``e_i`` over ``sqrt(Cov(e)_ii)``); the
largest above the gate is taken out and the update done again, one row at a time. A change
between steps is often far better known from the step's own rows than from the prediction (a
carrier-phase difference: cm, against metres of motion-model noise), so only this statistic
sees an error of one row.

The loop is sequential in time; each step costs a few small matrix products (state
dimension ``m`` ~ 10, ``n_t`` measurements).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

__all__ = ["FilterResult", "FreeRows", "kalman_filter", "rts_smooth", "kalman_update", "free_update",
           "clone_transition", "clone_prior"]

_NO_REDUNDANCY = 1e-10  # a free row's residual variance (whitened) below this: the row is not tested


@dataclass(frozen=True)
class FilterResult:
    """Filtered and predicted moments of every step.

    Attributes
    ----------
    x, P : ``(T, m)``, ``(T, m, m)`` filtered means and covariances (after step t's update).
    x_pred, P_pred : the same before the update (``x_pred[0] = m_0``).
    innovations : per step ``(n_t,)`` innovations ``y_t - H_t x-_t`` (NaN: rejected by the gate).
    free_tests : per step the w-test statistics of the free rows (module docstring; NaN: rejected
        by the gate; empty without free rows).
    """

    x: F64
    P: F64
    x_pred: F64
    P_pred: F64
    innovations: tuple[F64, ...]
    free_tests: tuple[F64, ...] = field(default=())


@dataclass(frozen=True)
class FreeRows:
    """Rows ``y = H x + G c + v`` of one step, ``v ~ N(0, diag(r))``, ``c`` without prior.

    Attributes
    ----------
    H : ``(n, m)``, y : ``(n,)``, r : ``(n,)`` rows, values and variances (> 0).
    G : ``(n, p)`` columns of the nuisance parameters (a column without a nonzero entry is ignored).
    """

    H: F64
    y: F64
    r: F64
    G: F64


def kalman_update(x: F64, P: F64, H: F64, y: F64, r: F64, gate: float | None = None,
                  groups: NDArray[np.int64] | None = None) -> tuple[F64, F64, F64]:
    """One measurement update (Joseph form); returns ``(x+, P+, innovation)``.

    Parameters
    ----------
    x : ``(m,)``, P : ``(m, m)`` prior mean and covariance.
    H : ``(n, m)``, y : ``(n,)``, r : ``(n,)`` measurement rows, values and variances.
    gate : rows whose normalized innovation ``|nu_i| / sqrt(S_ii)`` exceeds it are not used
        (their innovation is returned as NaN) -- while they are at most half of the rows of their
        group: when more exceed it, the prior is what is wrong (a manoeuvre the motion model did
        not expect) and every row of the group is used. None uses every row.
    groups : ``(n,)`` group of every row for the rule of the half (None: one group).

    Examples
    --------
    >>> import numpy as np
    >>> x, P, nu = kalman_update(np.zeros(1), np.eye(1), np.ones((1, 1)), np.array([2.0]), np.array([1.0]))
    >>> round(float(x[0]), 12), round(float(P[0, 0]), 12), float(nu[0])
    (1.0, 0.5, 2.0)
    """
    nu = y - H @ x
    if nu.size == 0:
        return x, P, nu
    PHt = P @ H.T
    S = H @ PHt
    S[np.diag_indices_from(S)] += r
    if gate is not None:
        out = nu**2 > gate**2 * np.diag(S)
        g = np.zeros(nu.size, dtype=np.int64) if groups is None else np.asarray(groups)
        drop = np.zeros(nu.size, dtype=bool)
        for k in np.unique(g[out]):
            sel = g == k
            if 2 * np.count_nonzero(out & sel) <= np.count_nonzero(sel):
                drop |= out & sel
        if drop.any():
            keep = ~drop
            x_new, P_new, _ = kalman_update(x, P, H[keep], y[keep], r[keep])
            return x_new, P_new, np.where(keep, nu, np.nan)
    try:
        K = np.linalg.solve(S, PHt.T).T  # LU: S is symmetric positive definite; cheaper per call than Cholesky in scipy
    except np.linalg.LinAlgError:  # S numerically singular (huge prior against tiny variances)
        K = np.linalg.lstsq(S, PHt.T, rcond=None)[0].T
    IKH = np.eye(x.size) - K @ H
    P_new = IKH @ P @ IKH.T + (K * r) @ K.T
    return x + K @ nu, 0.5 * (P_new + P_new.T), nu


def _projected(rows: FreeRows, keep: NDArray[np.bool_]) -> tuple[F64, F64, F64]:
    """The kept rows whitened and projected off the nuisance columns: ``(Q2, Q2^T H_w, Q2^T y_w)``,
    ``Q2`` ``(n_kept, n_kept - rank G)`` orthonormal (rows in the order of the kept rows)."""
    s = 1.0 / np.sqrt(rows.r[keep])
    G = rows.G[keep]
    G = G[:, np.any(G != 0.0, axis=0)] * s[:, None]
    if G.shape[1]:
        U, sv, _ = np.linalg.svd(G, full_matrices=True)
        rank = int(np.count_nonzero(sv > sv[0] * max(G.shape) * np.finfo(float).eps))
        Q2 = U[:, rank:]
    else:
        Q2 = np.eye(s.size)
    return Q2, Q2.T @ (rows.H[keep] * s[:, None]), Q2.T @ (rows.y[keep] * s)


def free_update(x: F64, P: F64, rows: FreeRows, gate: float | None = None) -> tuple[F64, F64, F64]:
    """Update with rows whose nuisance parameters are free; returns ``(x+, P+, w)``.

    ``w`` ``(n,)``: every row's w-test statistic at the update, ``e_i / sqrt(Cov(e)_ii)`` with ``e``
    the whitened residuals (nuisance re-estimated) -- the innovation of row ``i`` predicted from the
    prior and the other rows, over its sigma; 0 for a row without redundancy (alone with its
    nuisance parameter), NaN for a row the gate took out. ``gate``: while the largest ``|w_i|``
    exceeds it, that row is taken out and the update done again (None: every row is used).

    Notes
    -----
    With ``z = Q2^T R^(-1/2) y`` (unit variances, free of ``c``) and the innovation ``nu = z - Hz x-``,
    ``S = Hz P- Hz^T + I``: the residual after the update is ``z - Hz x+ = S^-1 nu``, of covariance
    ``S^-1``, and ``e = Q2 S^-1 nu``, ``Cov(e) = Q2 S^-1 Q2^T``.

    Examples
    --------
    >>> import numpy as np
    >>> rows = FreeRows(np.array([[1.0], [-1.0]]), np.array([3.0, 1.0]), np.ones(2), np.ones((2, 1)))
    >>> x, P, w = free_update(np.zeros(1), np.eye(1), rows)  # y1 - y2 = 2 x: one row, x = 1 * (2 / (2 + 1))
    >>> round(float(x[0]), 12), round(float(P[0, 0]), 12)
    (0.666666666667, 0.333333333333)
    """
    n = rows.y.size
    keep = np.ones(n, dtype=bool)
    while True:
        Q2, Hz, z = _projected(rows, keep)
        x_new, P_new, nu = kalman_update(x, P, Hz, z, np.ones(z.size))
        w = np.full(n, np.nan)
        if z.size == 0:
            w[keep] = 0.0
            return x_new, P_new, w
        S = Hz @ P @ Hz.T + np.eye(z.size)
        S_inv_nu, S_inv_Q2t = np.split(np.linalg.solve(S, np.column_stack([nu, Q2.T])), [1], axis=1)
        e = Q2 @ S_inv_nu[:, 0]
        var = np.einsum("ij,ji->i", Q2, S_inv_Q2t)
        w[keep] = np.where(var > _NO_REDUNDANCY, e / np.sqrt(np.where(var > _NO_REDUNDANCY, var, 1.0)), 0.0)
        worst = int(np.nanargmax(np.abs(w)))
        if gate is None or abs(w[worst]) <= gate:
            return x_new, P_new, w
        keep[worst] = False


def clone_transition(F: F64, Q: F64, cloned: NDArray[np.intp]) -> tuple[F64, F64]:
    """Transition and process noise of the state augmented with a copy of the previous state's
    components ``cloned``: ``[x_t, x_{t-1}[cloned]] = [[F, 0], [E, 0]] [x_{t-1}, .] + [w_t, 0]``.

    ``F``, ``Q``: ``(T, m, m)`` or ``(m, m)``; returns the same with ``m + len(cloned)``.

    Examples
    --------
    >>> import numpy as np
    >>> Fa, Qa = clone_transition(np.array([[1.0, 1.0], [0.0, 1.0]]), np.eye(2), np.array([0]))
    >>> Fa.tolist(), float(Qa[2, 2])
    ([[1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]], 0.0)
    """
    m, c = F.shape[-1], len(cloned)
    Fa = np.zeros((*F.shape[:-2], m + c, m + c))
    Qa = np.zeros_like(Fa)
    Fa[..., :m, :m] = F
    Fa[..., m + np.arange(c), cloned] = 1.0
    Qa[..., :m, :m] = Q
    return Fa, Qa


def clone_prior(m0: F64, P0: F64, cloned: NDArray[np.intp]) -> tuple[F64, F64]:
    """The first augmented state: the clone a copy of the components ``cloned`` (fully correlated)."""
    E = np.eye(m0.size)[cloned]
    A = np.vstack([np.eye(m0.size), E])
    return A @ m0, A @ P0 @ A.T


def kalman_filter(m0: F64, P0: F64, F: F64, Q: F64, H: Sequence[F64], y: Sequence[F64], r: Sequence[F64],
                  gate: float | Sequence[float | None] | None = None, *,
                  groups: Sequence[NDArray[np.int64] | None] | None = None,
                  free: Sequence[FreeRows | None] | None = None) -> FilterResult:
    """Run the filter over ``T`` steps.

    Parameters
    ----------
    m0 : ``(m,)``, P0 : ``(m, m)``
        Prior of the first state.
    F, Q : ``(T, m, m)``
        Transition from step ``t-1`` to ``t`` and its process-noise covariance (index 0 unused).
    H, y, r : sequences of length ``T``
        Per step: rows ``(n_t, m)``, measurements ``(n_t,)``, variances ``(n_t,)``.
    gate : the gate (module docstring), one for every step or one per step (None: every row is used).
    groups : per step the group of every row of ``H`` for the gate's rule of the half (None: one).
    free : per step the rows with free nuisance parameters (:class:`FreeRows`) or None; they
        update the state after the rows of ``H``.
    """
    T, m = len(y), m0.size
    xs, Ps = np.empty((T, m)), np.empty((T, m, m))
    xp, Pp = np.empty((T, m)), np.empty((T, m, m))
    nus, tests = [], []
    gates = [gate] * T if gate is None or np.isscalar(gate) else list(gate)  # type: ignore[arg-type]
    x, P = np.asarray(m0, dtype=np.float64), np.asarray(P0, dtype=np.float64)
    for t in range(T):
        if t > 0:
            x = F[t] @ x
            P = F[t] @ P @ F[t].T + Q[t]
        xp[t], Pp[t] = x, P
        x, P, nu = kalman_update(x, P, H[t], y[t], r[t], gates[t], None if groups is None else groups[t])
        rows = None if free is None else free[t]
        if rows is not None:
            x, P, w = free_update(x, P, rows, gates[t])
            tests.append(w)
        elif free is not None:
            tests.append(np.zeros(0))
        xs[t], Ps[t] = x, P
        nus.append(nu)
    return FilterResult(xs, Ps, xp, Pp, tuple(nus), tuple(tests))


def rts_smooth(result: FilterResult, F: F64) -> tuple[F64, F64]:
    """Rauch-Tung-Striebel smoothed means ``(T, m)`` and covariances ``(T, m, m)``.

    ``F`` ``(T, m, m)``: the transitions the filter used (``F[t]`` from ``t-1`` to ``t``).
    """
    x, P = result.x.copy(), result.P.copy()
    for t in range(x.shape[0] - 2, -1, -1):
        Pp = result.P_pred[t + 1]
        C = np.linalg.solve(Pp, F[t + 1] @ result.P[t]).T
        x[t] = result.x[t] + C @ (x[t + 1] - result.x_pred[t + 1])
        Pt = result.P[t] + C @ (P[t + 1] - Pp) @ C.T
        P[t] = 0.5 * (Pt + Pt.T)
    return x, P
