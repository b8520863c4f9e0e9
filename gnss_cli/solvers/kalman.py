"""Linear Kalman filter and Rauch-Tung-Striebel smoother (matrices only, no GNSS).

Model, steps ``t = 0 .. T-1``::

    x_0 ~ N(m_0, P_0),    x_t = F_t x_{t-1} + w_t,  w_t ~ N(0, Q_t)   (t >= 1)
    y_t = H_t x_t + v_t,  v_t ~ N(0, diag(r_t))

Each step may have its own number of measurements (0 included). The filter's update is the
Joseph form ``P+ = (I - K H) P- (I - K H)^T + K R K^T`` (symmetric and positive semidefinite
in floating point for any gain), with ``K = P- H^T S^-1``, ``S = H P- H^T + R`` (solved, not inverted). The RTS smoother runs backwards:
``C_t = P_t F_{t+1}^T (P-_{t+1})^-1``, ``x^s_t = x_t + C_t (x^s_{t+1} - x-_{t+1})``,
``P^s_t = P_t + C_t (P^s_{t+1} - P-_{t+1}) C_t^T``. For this linear-Gaussian model the
smoothed means are the batch MAP estimate (the minimiser of the stacked weighted least
squares over all states) and the smoothed covariances the matching blocks of the inverse of
its information matrix; the tests check both.

The loop is sequential in time; each step costs a few small matrix products (state
dimension ``m`` ~ 10, ``n_t`` measurements).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

__all__ = ["FilterResult", "kalman_filter", "rts_smooth", "kalman_update"]


@dataclass(frozen=True)
class FilterResult:
    """Filtered and predicted moments of every step.

    Attributes
    ----------
    x, P : ``(T, m)``, ``(T, m, m)`` filtered means and covariances (after step t's update).
    x_pred, P_pred : the same before the update (``x_pred[0] = m_0``).
    innovations : per step ``(n_t,)`` innovations ``y_t - H_t x-_t`` (NaN: rejected by the gate).
    """

    x: F64
    P: F64
    x_pred: F64
    P_pred: F64
    innovations: tuple[F64, ...]


def kalman_update(x: F64, P: F64, H: F64, y: F64, r: F64, gate: float | None = None) -> tuple[F64, F64, F64]:
    """One measurement update (Joseph form); returns ``(x+, P+, innovation)``.

    Parameters
    ----------
    x : ``(m,)``, P : ``(m, m)`` prior mean and covariance.
    H : ``(n, m)``, y : ``(n,)``, r : ``(n,)`` measurement rows, values and variances.
    gate : rows whose normalized innovation ``|nu_i| / sqrt(S_ii)`` exceeds it are not used
        (their innovation is returned as NaN) -- while they are at most half of the rows: when
        more exceed it, the prior is what is wrong (a manoeuvre the motion model did not
        expect) and every row is used. None uses every row.

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
        keep = nu**2 <= gate**2 * np.diag(S)
        if not keep.all() and 2 * keep.sum() >= keep.size:
            nu = np.where(keep, nu, np.nan)
            H, r, PHt, S = H[keep], r[keep], PHt[:, keep], S[np.ix_(keep, keep)]
            x_new, P_new, _ = kalman_update(x, P, H, y[keep], r)
            return x_new, P_new, nu
    try:
        K = np.linalg.solve(S, PHt.T).T  # LU: S is symmetric positive definite; cheaper per call than Cholesky in scipy
    except np.linalg.LinAlgError:  # S numerically singular (huge prior against tiny variances)
        K = np.linalg.lstsq(S, PHt.T, rcond=None)[0].T
    IKH = np.eye(x.size) - K @ H
    P_new = IKH @ P @ IKH.T + (K * r) @ K.T
    return x + K @ nu, 0.5 * (P_new + P_new.T), nu


def kalman_filter(m0: F64, P0: F64, F: F64, Q: F64, H: Sequence[F64], y: Sequence[F64], r: Sequence[F64],
                  gate: float | Sequence[float | None] | None = None) -> FilterResult:
    """Run the filter over ``T`` steps.

    Parameters
    ----------
    m0 : ``(m,)``, P0 : ``(m, m)``
        Prior of the first state.
    F, Q : ``(T, m, m)``
        Transition from step ``t-1`` to ``t`` and its process-noise covariance (index 0 unused).
    H, y, r : sequences of length ``T``
        Per step: rows ``(n_t, m)``, measurements ``(n_t,)``, variances ``(n_t,)``.
    gate : innovation gate of :func:`kalman_update`, one for every step or one per step
        (None: every row is used).
    """
    T, m = len(y), m0.size
    xs, Ps = np.empty((T, m)), np.empty((T, m, m))
    xp, Pp = np.empty((T, m)), np.empty((T, m, m))
    nus = []
    gates = [gate] * T if gate is None or np.isscalar(gate) else list(gate)  # type: ignore[arg-type]
    x, P = np.asarray(m0, dtype=np.float64), np.asarray(P0, dtype=np.float64)
    for t in range(T):
        if t > 0:
            x = F[t] @ x
            P = F[t] @ P @ F[t].T + Q[t]
        xp[t], Pp[t] = x, P
        x, P, nu = kalman_update(x, P, H[t], y[t], r[t], gates[t])
        xs[t], Ps[t] = x, P
        nus.append(nu)
    return FilterResult(xs, Ps, xp, Pp, tuple(nus))


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
