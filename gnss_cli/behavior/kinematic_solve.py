"""Positions and velocities of a whole segment tied by a kinematic kernel, from per-epoch normal equations.

The behavior of ``w_t = (x_t, v_t)`` (position m, velocity m/s) with the kernel of lag ``l``::

    l = 1:  x_{t+1} - x_t = dt/2 (v_t + v_{t+1})                             (trapezoid)
    l = 2:  x_{t+1} - x_t = dt/12 (-v_{t-1} + 8 v_t + 5 v_{t+1})              (quadratic interpolation of v)
    l = 3:  x_{t+1} - x_t = dt/24 (-v_{t-1} + 13 v_t + 13 v_{t+1} - v_{t+2})  (cubic interpolation of v)

(the lag-l rule integrates the polynomial of degree l through l + 1 velocities,
:func:`step_weights`, so it is exact for velocities of degree l; at the ends of a segment the
same number of velocities is taken one-sided, e.g. ``dt/24 (9 v_0 + 19 v_1 - 5 v_2 + v_3)``). The velocities are free inputs: the behavior's trajectories over ``N`` epochs are
``x_0`` and ``v_0 ... v_{N-1}``. Each epoch observes its position through the clock-reduced
pseudorange normals ``(M_t, r_t, s_t)`` (relative to a linearization point ``x_nom_t``) and its
velocity through the drift-reduced range-rate normals ``(Md_t, rd_t, sd_t)``
(:func:`gnss_cli.behavior.window_solve.reduce_epochs`). With ``z_t = x_t - x_nom_t``::

    min  sum_t  z^T M z - 2 z^T r + v^T Md v - 2 v^T rd  +  sum_t |v_{t+1} - 2 v_t + v_{t-1}|^2 / (j^2 dt^4)
    s.t. the kernel equations,

plus, when given, ``sum_t [z_{t-1}; z_t]^T Mp_t [z_{t-1}; z_t] - 2 [z_{t-1}; z_t]^T rp_t`` of rows on two
consecutive positions (time-differenced carrier phase; their nuisance columns reduced), and
the last term a weak prior on the jerk (``j`` = :data:`JERK_SIGMA_M_S3`; a constant acceleration
costs nothing). With Doppler a velocity is observed to ~0.1 m/s, an information ~1e4 times the
prior's, which then does not bend the trajectory (the simulated flights and the Yamatogawa walk
gave the same 3D RMS to 1 mm with 1 or 3 m/s^3). It decides what the rows do not: velocities
no row observes, and the directions an epoch with 2-3 satellites leaves open, which the rows
observe only through the slow rotation of the satellite geometry (information ~3e-4 (m/s)^-2 on
a simulated flight). Measured there: ten 3-satellite epochs drifted 140 m along that direction
with a prior of 100 m/s^2 on the acceleration, 6 m with 10 m/s^2 (it pulls the unobserved
acceleration of a turn to zero), 1.4 m with 3 m/s^3 on the jerk; ten 2-satellite epochs 0.7 m,
four 1-satellite epochs 0.45 m. The equality-constrained problem is solved through its sparse KKT system (banded: O(N)).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import splu, spsolve

from gnss_cli.behavior.window_solve import EpochNormals

__all__ = ["KinematicSolution", "solve_kinematic", "kinematic_position_cov", "step_rule", "step_weights", "ACCEL_SIGMA_M_S2",
           "JERK_SIGMA_M_S3", "STEP_OFFSETS"]

F64 = NDArray[np.float64]

#: Sigma (m/s^2) of a weak prior on the change of velocity between epochs (0: none).
ACCEL_SIGMA_M_S2 = 0.0
#: Sigma (m/s^3) of the weak prior on the second difference of the velocities (module docstring).
JERK_SIGMA_M_S3 = 3.0
#: Epoch offsets (from t) of the velocities of one step x_{t+1} - x_t, per lag, inside a segment.
STEP_OFFSETS = {1: (0, 1), 2: (-1, 0, 1), 3: (-1, 0, 1, 2)}


@lru_cache(maxsize=64)
def _weights(offsets: tuple[int, ...]) -> tuple[float, ...]:
    o = np.asarray(offsets, dtype=np.float64)
    j = np.arange(o.size)
    return tuple(np.linalg.solve(o[None, :] ** j[:, None], 1.0 / (j + 1.0)).tolist())


def step_weights(offsets: tuple[int, ...]) -> F64:
    """Weights ``c_k`` of ``x_{t+1} - x_t = dt sum_k c_k v_{t+k}``: the integral over ``[t, t+1]`` of the
    polynomial interpolating the velocities at ``t + offsets`` (exact for velocities of degree < len(offsets)).

    >>> step_weights((-1, 0, 1, 2)) * 24
    array([-1., 13., 13., -1.])
    """
    return np.array(_weights(tuple(int(v) for v in offsets)))


def step_rule(t: int, n: int, lag: int) -> tuple[NDArray[np.intp], F64]:
    """Offsets and weights of step ``t`` of a segment of ``n`` epochs: the lag's offsets, shifted
    to stay inside the segment (one-sided at its ends), fewer where the segment is shorter."""
    offs = np.asarray(STEP_OFFSETS[min(max(lag, 1), 3, n - 1)])
    offs = offs + max(0, -(t + offs[0])) - max(0, t + offs[-1] - (n - 1))
    return offs, step_weights(tuple(int(o) for o in offs))


@dataclass(frozen=True, slots=True)
class KinematicSolution:
    """Corrections ``z (N, 3)`` (m, to the linearization points), velocities ``v (N, 3)`` (m/s),
    the weighted misfit and its degrees of freedom (rows - nuisance columns - 3 N - 3)."""

    z: F64
    v: F64
    misfit: float
    dof: int


def _constraints(dt_s: F64, lag: int) -> sp.csr_matrix:
    """Rows ``x_{t+1} - x_t - sum_k c_k dt v_{t+k}`` (scalar, per coordinate) on ``[x_0..x_{N-1}, v_0..v_{N-1}]``."""
    n = dt_s.size + 1
    rows, cols, vals = [], [], []
    for t in range(n - 1):
        offs, wts = step_rule(t, n, lag)
        rows += [t, t]
        cols += [t + 1, t]
        vals += [1.0, -1.0]
        for o, w in zip(offs, wts):
            rows.append(t)
            cols.append(n + t + o)
            vals.append(-w * dt_s[t])
    return sp.csr_matrix((vals, (rows, cols)), shape=(n - 1, 2 * n))


def _prior(dt_s: F64) -> sp.csr_matrix:
    """Information ``(N, N)`` of the weak prior on the velocities (one coordinate)."""
    n = dt_s.size + 1
    out = sp.csr_matrix((n, n))
    if ACCEL_SIGMA_M_S2 > 0:
        d1 = sp.diags([-np.ones(n - 1), np.ones(n - 1)], [0, 1], shape=(n - 1, n))
        out = out + d1.T @ sp.diags(1.0 / (ACCEL_SIGMA_M_S2 * dt_s) ** 2) @ d1
    if JERK_SIGMA_M_S3 > 0 and n > 2:
        d2 = sp.diags([np.ones(n - 2), -2 * np.ones(n - 2), np.ones(n - 2)], [0, 1, 2], shape=(n - 2, n))
        h = 0.5 * (dt_s[1:] + dt_s[:-1])
        out = out + d2.T @ sp.diags(1.0 / (JERK_SIGMA_M_S3 * h**2) ** 2) @ d2
    return out.tocsr()


def _pair_information(M_ph: F64) -> sp.csr_matrix:
    """``(3N, 3N)`` information of the epoch pairs: ``M_ph[t]`` ``(6, 6)`` on ``[x_{t-1}, x_t]`` (row 0 unused)."""
    n = M_ph.shape[0]
    j = np.arange(1, n)
    idx = 3 * (j - 1)[:, None] + np.arange(6)[None, :]  # (n - 1, 6) positions of [x_{t-1}, x_t]
    rows = np.broadcast_to(idx[:, :, None], (n - 1, 6, 6))
    cols = np.broadcast_to(idx[:, None, :], (n - 1, 6, 6))
    return sp.csr_matrix((M_ph[1:].ravel(), (rows.ravel(), cols.ravel())), shape=(3 * n, 3 * n))


def _kkt(M_pr: F64, M_rr: F64, dt_s: F64, lag: int, M_ph: F64 | None = None) -> sp.csc_matrix:
    """The KKT matrix ``[[H, G^T], [G, 0]]`` on ``[x (3N), v (3N), multipliers (3N - 3)]``."""
    n = M_pr.shape[0]
    G = sp.kron(_constraints(dt_s, lag), sp.eye(3), format="csr")  # coordinate fastest
    H = sp.block_diag([sp.block_diag(list(M_pr)), sp.block_diag(list(M_rr))], format="csr")
    if M_ph is not None and n > 1:
        H = H + sp.block_diag([_pair_information(M_ph), sp.csr_matrix((3 * n, 3 * n))], format="csr")
    if n > 1:
        H = H + sp.block_diag([sp.csr_matrix((3 * n, 3 * n)), sp.kron(_prior(dt_s), sp.eye(3))], format="csr")
    return sp.bmat([[H, G.T], [G, None]], format="csc")


def kinematic_position_cov(M_pr: F64, M_rr: F64, dt_s: F64, lag: int, *, piece: int = 120,
                           margin: int = 60, M_ph: F64 | None = None) -> F64:
    """Covariance blocks ``(N, 3, 3)`` of the positions of :func:`solve_kinematic` (units of ``1 / M``).

    The position block of the inverse KKT matrix (the equality-constrained estimator's
    covariance), for the information ``M_pr`` (pseudoranges) and ``M_rr`` (range rates). A
    segment longer than ``piece`` epochs is cut into pieces, each solved with ``margin`` epochs of
    its neighbours on either side (``M_ph``: the information of the epoch pairs, as in
    :func:`solve_kinematic`): less information than the whole segment, so the blocks are
    then slightly larger (conservative), never smaller. On a simulated 20-min 1 Hz flight with
    Doppler the defaults gave traces within 0.2 % (median; 3.4 % at most) of the whole-segment
    inverse at an eighth of its cost (the cost grows with ``piece + 2 margin`` per epoch).
    """
    n = M_pr.shape[0]
    cov = np.empty((n, 3, 3))
    for a in range(0, n, piece):
        b = min(n, a + piece)
        lo, hi = max(0, a - margin), min(n, b + margin)
        ph = None
        if M_ph is not None:
            ph = M_ph[lo:hi].copy()
            ph[0] = 0.0  # the pair ending at the piece's first epoch starts outside it
        lu = splu(_kkt(M_pr[lo:hi], M_rr[lo:hi], dt_s[lo : hi - 1], lag, ph))
        size = lu.shape[0]
        for c0 in range(3 * (a - lo), 3 * (b - lo), 384):
            c1 = min(3 * (b - lo), c0 + 384)
            rhs = np.zeros((size, c1 - c0))
            rhs[np.arange(c0, c1), np.arange(c1 - c0)] = 1.0
            x = lu.solve(rhs)[: 3 * (hi - lo)]
            for j in range(c0, c1):
                t = j // 3
                cov[lo + t, :, j % 3] = x[3 * t : 3 * t + 3, j - c0]
    return 0.5 * (cov + cov.transpose(0, 2, 1))


def solve_kinematic(pr: EpochNormals, rr: EpochNormals, step_m: F64, dt_s: F64, lag: int = 1,
                    ph: EpochNormals | None = None) -> KinematicSolution:
    """Solve one segment (module docstring).

    Parameters
    ----------
    pr, rr : EpochNormals
        Pseudorange normals (relative to the linearization points) and range-rate normals
        (absolute velocity) of the segment's ``N`` epochs.
    step_m : ``(N - 1, 3)``
        ``x_nom_{t+1} - x_nom_t``, m.
    dt_s : ``(N - 1,)``
        Time steps, s.
    lag : 1, 2 or 3
        Kernel (:data:`STEP_RULES`).
    ph : EpochNormals, optional
        Normals of rows on two consecutive positions (time-differenced carrier phase), the
        nuisance columns reduced: ``ph.M[t]`` ``(6, 6)`` and ``ph.r[t]`` ``(6,)`` on
        ``[z_{t-1}, z_t]``; row 0 is not used (the term ``z^T M z - 2 z^T r`` joins the sum).

    Returns
    -------
    KinematicSolution
    """
    n = pr.M.shape[0]
    kkt = _kkt(pr.M, rr.M, dt_s, lag, None if ph is None else ph.M)
    r_x = pr.r.copy()
    if ph is not None and n > 1:
        r_x[:-1] += ph.r[1:, :3]
        r_x[1:] += ph.r[1:, 3:]
    rhs = np.concatenate([r_x.ravel(), rr.r.ravel()])
    c = -step_m.ravel()  # z_{t+1} - z_t - (velocity terms) = -(x_nom_{t+1} - x_nom_t)
    sol = spsolve(kkt, np.concatenate([rhs, c]))
    z, v = sol[: 3 * n].reshape(n, 3), sol[3 * n : 6 * n].reshape(n, 3)
    mis = float(pr.s.sum() - 2 * np.sum(z * pr.r) + np.einsum("ti,tij,tj->", z, pr.M, z)
                + rr.s.sum() - 2 * np.sum(v * rr.r) + np.einsum("ti,tij,tj->", v, rr.M, v))
    dof = int(pr.n_rows.sum() - pr.n_free.sum() + rr.n_rows.sum() - rr.n_free.sum() - 3 * n - 3)
    if ph is not None and n > 1:
        z6 = np.hstack([z[:-1], z[1:]])
        mis += float(ph.s[1:].sum() - 2 * np.sum(z6 * ph.r[1:]) + np.einsum("ti,tij,tj->", z6, ph.M[1:], z6))
        dof += int(ph.n_rows[1:].sum() - ph.n_free[1:].sum())
    return KinematicSolution(z, v, mis, dof)
