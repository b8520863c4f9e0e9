"""Positions and velocities of a whole segment under a fixed motion model, from per-epoch normal equations.

The state of epoch ``t`` is ``x_t`` (position m) and, by motion, ``v_t`` (velocity m/s) and
``a_t`` (acceleration m/s^2). Each epoch observes its position through the clock-reduced
pseudorange normals ``(M_t, r_t, s_t)`` (relative to a linearization point ``x_nom_t``), its
velocity through the drift-reduced range-rate normals ``(Md_t, rd_t, sd_t)``
(:func:`gnss_cli.behavior.window_solve.reduce_epochs`) when there are range rates, and, when
given, pairs of consecutive positions through rows on ``[z_{t-1}; z_t]`` (time-differenced
carrier phase, nuisance columns reduced: ``z^T Mp_t z - 2 z^T rp_t``). With ``z_t = x_t - x_nom_t``
the segment solves::

    min  sum_t  z^T M z - 2 z^T r + v^T Md v - 2 v^T rd   +   motion terms

The motions (:class:`Motion`, per ECEF axis):

- ``quadrature``: ``x_{t+1} - x_t = dt sum_k c_k v_{t+k}`` as equality constraints, the lag-l
  rule integrating the polynomial of degree l through l + 1 velocities (:func:`step_weights`,
  exact for velocities of degree l; one-sided at the ends of a segment, e.g.
  ``dt/24 (9 v_0 + 19 v_1 - 5 v_2 + v_3)``)::

      l = 1:  x_{t+1} - x_t = dt/2 (v_t + v_{t+1})                             (trapezoid)
      l = 2:  x_{t+1} - x_t = dt/12 (-v_{t-1} + 8 v_t + 5 v_{t+1})              (quadratic)
      l = 3:  x_{t+1} - x_t = dt/24 (-v_{t-1} + 13 v_t + 13 v_{t+1} - v_{t+2})  (cubic)

  The velocities are free inputs, with a weak prior on their second difference,
  ``sum_t |v_{t+1} - 2 v_t + v_{t-1}|^2 / (j^2 dt^4)`` (``j`` = :data:`JERK_SIGMA_M_S3`; a
  constant acceleration costs nothing). With Doppler a velocity is observed to ~0.1 m/s, an
  information ~1e4 times the prior's, which then does not bend the trajectory (the simulated
  flights and the Yamatogawa walk gave the same 3D RMS to 1 mm with 1 or 3 m/s^3). It decides
  what the rows do not: velocities no row observes, and the directions an epoch with 2-3
  satellites leaves open, which the rows observe only through the slow rotation of the
  satellite geometry (information ~3e-4 (m/s)^-2 on a simulated flight). Measured there: ten
  3-satellite epochs drifted 140 m along that direction with a prior of 100 m/s^2 on the
  acceleration, 6 m with 10 m/s^2, 1.4 m with 3 m/s^3 on the jerk; ten 2-satellite epochs
  0.7 m, four 1-satellite epochs 0.45 m. The prior is not part of the model's misfit.
- ``cv``: constant velocity, white acceleration of PSD ``q_a`` (m^2/s^3): the process residual
  ``[x_{t+1} - x_t - dt v_t; v_{t+1} - v_t]`` has the covariance
  ``q_a [[dt^3/3, dt^2/2], [dt^2/2, dt]]`` and enters the sum with its inverse
  (``[[12/dt^3, -6/dt^2], [-6/dt^2, 4/dt]] / q_a``). Without a prior on the first state this is
  the fixed-interval (RTS) smoother of the linear model with a diffuse start.
- ``ca``: constant acceleration, white jerk of PSD ``q_j`` (m^2/s^5): the residual of
  ``s_{t+1} = F s_t`` on ``s = (x, v, a)``, covariance
  ``q_j [[dt^5/20, dt^4/8, dt^3/6], [dt^4/8, dt^3/3, dt^2/2], [dt^3/6, dt^2/2, dt]]``.
- ``static``: ``x_{t+1} = x_t`` as equality constraints (one position per segment); the
  velocities are zero and the range rates only count in the misfit.

The process terms of ``cv`` and ``ca`` are part of the model: they count in the misfit and
their rows in the degrees of freedom. The equality-constrained problem is solved through its
sparse KKT system (banded: O(N)); :attr:`KinematicSolution.rcond` is an estimate of its
reciprocal condition number (rows and columns scaled to unit largest entry), 0 when it is
singular.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import LinearOperator, onenormest, splu

from gnss_cli.behavior.window_solve import EpochNormals
from gnss_cli.errors import ConfigError

__all__ = ["KinematicSolution", "Motion", "MotionTerms", "MOTIONS", "motion_terms", "solve_kinematic",
           "kinematic_position_cov", "step_rule", "step_weights", "JERK_SIGMA_M_S3", "STEP_OFFSETS"]

F64 = NDArray[np.float64]

#: The fixed motion models (module docstring).
MOTIONS = ("quadrature", "cv", "ca", "static")
#: Sigma (m/s^3) of the weak prior of the quadrature motion on the second difference of the velocities.
JERK_SIGMA_M_S3 = 3.0
#: Epoch offsets (from t) of the velocities of one step x_{t+1} - x_t, per lag, inside a segment.
STEP_OFFSETS = {1: (0, 1), 2: (-1, 0, 1), 3: (-1, 0, 1, 2)}


@dataclass(frozen=True, slots=True)
class Motion:
    """A fixed motion model (module docstring).

    Attributes
    ----------
    name : one of :data:`MOTIONS`.
    lag : the quadrature rule's lag (1-3; larger lags use the cubic rule); other motions ignore it.
    accel_psd_m2_s3 : white-acceleration PSD of ``cv``, m^2/s^3 per axis.
    jerk_psd_m2_s5 : white-jerk PSD of ``ca``, m^2/s^5 per axis.
    """

    name: str = "quadrature"
    lag: int = 3
    accel_psd_m2_s3: float = 10.0
    jerk_psd_m2_s5: float = 10.0

    def validated(self) -> "Motion":
        """Self, after checking every value; raises :class:`~gnss_cli.errors.ConfigError` naming it."""
        if self.name not in MOTIONS:
            raise ConfigError(f"motion: expected one of {', '.join(MOTIONS)}; received {self.name!r}")
        if self.name == "quadrature" and (isinstance(self.lag, bool) or not isinstance(self.lag, (int, np.integer))
                                          or self.lag < 1):
            raise ConfigError(f"lag: expected an integer >= 1 for the quadrature motion; received {self.lag!r}")
        for key in ("accel_psd_m2_s3", "jerk_psd_m2_s5"):
            if not float(getattr(self, key)) > 0:
                raise ConfigError(f"{key}: expected > 0; received {getattr(self, key)!r}")
        return self

    @property
    def n_kin(self) -> int:
        """State blocks per epoch: position (static); position, velocity; position, velocity, acceleration (ca)."""
        return {"static": 1, "ca": 3}.get(self.name, 2)


@dataclass(frozen=True, slots=True)
class MotionTerms:
    """The motion of a segment of ``N`` epochs, per coordinate, on ``u = [x_0..x_{N-1}, v_0.., a_0..]``
    (the state blocks of :attr:`Motion.n_kin`) and the nominal steps ``s_t = x_nom_{t+1} - x_nom_t``.

    Equality constraints ``hard @ u + hard_step @ s = 0``; cost
    ``(soft @ u + soft_step @ s)^T soft_weight (soft @ u + soft_step @ s)``; ``counted``: how many
    of the soft rows, the first ones, are part of the model's misfit and degrees of freedom (process
    noise, switch rows); the rest are a prior (the quadrature motion's on the velocities).
    """

    hard: sp.csr_matrix
    hard_step: sp.csr_matrix
    soft: sp.csr_matrix
    soft_step: sp.csr_matrix
    soft_weight: sp.csr_matrix
    counted: int


@dataclass(frozen=True, slots=True)
class KinematicSolution:
    """Corrections ``z (N, 3)`` (m, to the linearization points), velocities ``v (N, 3)`` (m/s; zero
    for ``static``), the weighted misfit, its degrees of freedom and the reciprocal condition
    estimate of the system (module docstring; 0 and NaN estimates when it is singular)."""

    z: F64
    v: F64
    misfit: float
    dof: int
    rcond: float


def _interval_weights(nodes: F64) -> F64:
    """Weights ``c`` with ``sum_k c_k p(nodes_k) = int_0^1 p`` for every polynomial ``p`` of degree
    below ``len(nodes)`` (the nodes in units of the step, distinct)."""
    j = np.arange(nodes.size)
    return np.linalg.solve(nodes[None, :] ** j[:, None], 1.0 / (j + 1.0))


@lru_cache(maxsize=64)
def _weights(offsets: tuple[int, ...]) -> tuple[float, ...]:
    return tuple(_interval_weights(np.asarray(offsets, dtype=np.float64)).tolist())


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


def _quadrature_rows(dt_s: F64, lag: int) -> sp.csr_matrix:
    """Rows ``x_{t+1} - x_t - sum_k c_k dt v_{t+k}`` (scalar, per coordinate) on ``[x_0..x_{N-1}, v_0..v_{N-1}]``.

    Where the steps around ``t`` differ (a missed epoch), ``c`` interpolates the velocities at their
    own times (:func:`_interval_weights`), so the rule stays exact for velocities of its degree."""
    n = dt_s.size + 1
    t_s = np.concatenate([[0.0], np.cumsum(dt_s)])
    rows, cols, vals = [], [], []
    for t in range(n - 1):
        offs, wts = step_rule(t, n, lag)
        tau = (t_s[t + offs] - t_s[t]) / dt_s[t]
        if np.abs(tau - offs).max() > 1e-6:
            wts = _interval_weights(tau)
        rows += [t, t]
        cols += [t + 1, t]
        vals += [1.0, -1.0]
        for o, w in zip(offs, wts):
            rows.append(t)
            cols.append(n + t + o)
            vals.append(-w * dt_s[t])
    return sp.csr_matrix((vals, (rows, cols)), shape=(n - 1, 2 * n))


def _transition(dt: F64, n_kin: int) -> F64:
    """``(S, n_kin, n_kin)`` transition of ``(x, v[, a])`` over each step ``dt (S,)``."""
    F = np.broadcast_to(np.eye(n_kin), (dt.size, n_kin, n_kin)).copy()
    F[:, 0, 1] = dt
    if n_kin == 3:
        F[:, 0, 2] = dt**2 / 2
        F[:, 1, 2] = dt
    return F


def _process_information(dt: F64, n_kin: int, psd: float) -> F64:
    """``(S, n_kin, n_kin)`` inverse of the process-noise covariance of each step (module docstring)."""
    if n_kin == 2:
        w = [[12 / dt**3, -6 / dt**2], [-6 / dt**2, 4 / dt]]
    else:
        w = [[720 / dt**5, -360 / dt**4, 60 / dt**3], [-360 / dt**4, 192 / dt**3, -36 / dt**2],
             [60 / dt**3, -36 / dt**2, 9 / dt]]
    return np.moveaxis(np.array(w), -1, 0) / psd


def _process_rows(dt_s: F64, n_kin: int) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """``s_{t+1} - F_t s_t`` on ``u`` (row ``n_kin t + i``) and the steps' coefficients (row ``n_kin t``)."""
    n = dt_s.size + 1
    F = _transition(dt_s, n_kin)
    t, i, j = np.meshgrid(np.arange(n - 1), np.arange(n_kin), np.arange(n_kin), indexing="ij")
    keep = F[t, i, j] != 0
    rows = np.concatenate([(n_kin * t + i)[:, :, 0].ravel(), (n_kin * t + i)[keep]])
    cols = np.concatenate([(i * n + t + 1)[:, :, 0].ravel(), (j * n + t)[keep]])
    vals = np.concatenate([np.ones((n - 1) * n_kin), -F[t, i, j][keep]])
    soft = sp.csr_matrix((vals, (rows, cols)), shape=(n_kin * (n - 1), n_kin * n))
    step = sp.csr_matrix((np.ones(n - 1), (n_kin * np.arange(n - 1), np.arange(n - 1))), shape=(n_kin * (n - 1), n - 1))
    return soft, step


def motion_terms(motion: Motion, dt_s: F64) -> MotionTerms:
    """The :class:`MotionTerms` of ``motion`` for a segment with time steps ``dt_s (N - 1,)`` (s)."""
    n = dt_s.size + 1
    m = motion.n_kin * n
    if motion.name in ("cv", "ca"):
        soft, step = _process_rows(dt_s, motion.n_kin)
        psd = motion.accel_psd_m2_s3 if motion.name == "cv" else motion.jerk_psd_m2_s5
        weight = sp.block_diag(list(_process_information(dt_s, motion.n_kin, psd)), format="csr") if n > 1 \
            else sp.csr_matrix((0, 0))
        return MotionTerms(sp.csr_matrix((0, m)), sp.csr_matrix((0, n - 1)), soft, step, weight, soft.shape[0])
    if motion.name == "static":
        hard = sp.diags([-np.ones(n - 1), np.ones(n - 1)], [0, 1], shape=(n - 1, n), format="csr")
        empty = sp.csr_matrix((0, m))
        return MotionTerms(hard, sp.eye(n - 1, format="csr"), empty, sp.csr_matrix((0, n - 1)), sp.csr_matrix((0, 0)), 0)
    hard = _quadrature_rows(dt_s, motion.lag)
    if n > 2 and JERK_SIGMA_M_S3 > 0:
        d2 = sp.diags([np.ones(n - 2), -2 * np.ones(n - 2), np.ones(n - 2)], [0, 1, 2], shape=(n - 2, n))
        soft = sp.hstack([sp.csr_matrix((n - 2, n)), d2], format="csr")
        h = 0.5 * (dt_s[1:] + dt_s[:-1])
        weight = sp.diags(1.0 / (JERK_SIGMA_M_S3 * h**2) ** 2, format="csr")
    else:
        soft, weight = sp.csr_matrix((0, m)), sp.csr_matrix((0, 0))
    return MotionTerms(hard, sp.eye(n - 1, format="csr"), soft, sp.csr_matrix((soft.shape[0], n - 1)), weight, 0)


def _pair_information(M_ph: F64) -> sp.csr_matrix:
    """``(3N, 3N)`` information of the epoch pairs: ``M_ph[t]`` ``(6, 6)`` on ``[x_{t-1}, x_t]`` (row 0 unused)."""
    n = M_ph.shape[0]
    j = np.arange(1, n)
    idx = 3 * (j - 1)[:, None] + np.arange(6)[None, :]  # (n - 1, 6) positions of [x_{t-1}, x_t]
    rows = np.broadcast_to(idx[:, :, None], (n - 1, 6, 6))
    cols = np.broadcast_to(idx[:, None, :], (n - 1, 6, 6))
    return sp.csr_matrix((M_ph[1:].ravel(), (rows.ravel(), cols.ravel())), shape=(3 * n, 3 * n))


def _kkt(M_pr: F64, M_rr: F64 | None, terms: MotionTerms, n_kin: int, M_ph: F64 | None = None) -> sp.csc_matrix:
    """The KKT matrix ``[[H, G^T], [G, 0]]`` on ``[u (3 n_kin N), multipliers]`` (coordinate fastest)."""
    n = M_pr.shape[0]
    eye3 = sp.eye(3)
    blocks = [sp.block_diag(list(M_pr))]
    if n_kin >= 2:
        blocks.append(sp.block_diag(list(M_rr)) if M_rr is not None else sp.csr_matrix((3 * n, 3 * n)))
    blocks += [sp.csr_matrix((3 * n, 3 * n))] * (n_kin - len(blocks))
    H = sp.block_diag(blocks, format="csr")
    if M_ph is not None and n > 1:
        H = H + sp.block_diag([_pair_information(M_ph), sp.csr_matrix((3 * n * (n_kin - 1),) * 2)], format="csr")
    if terms.soft.shape[0]:
        H = H + sp.kron(terms.soft.T @ terms.soft_weight @ terms.soft, eye3)
    if not terms.hard.shape[0]:
        return sp.csc_matrix(H)
    G = sp.kron(terms.hard, eye3, format="csr")
    return sp.bmat([[H, G.T], [G, None]], format="csc")


def _rcond(kkt: sp.csc_matrix, lu) -> float:  # type: ignore[no-untyped-def]
    """Reciprocal 1-norm condition estimate of ``kkt`` scaled to unit largest entry per row and column."""
    d = 1.0 / np.sqrt(np.maximum(abs(kkt).max(axis=1).toarray().ravel(), np.finfo(float).tiny))
    scaled = sp.diags(d) @ kkt @ sp.diags(d)
    norm = float(abs(scaled).sum(axis=0).max())
    inv = LinearOperator(kkt.shape, matvec=lambda x: lu.solve(np.ravel(x) / d) / d,
                         rmatvec=lambda x: lu.solve(np.ravel(x) / d, trans="T") / d, dtype=np.float64)
    est = float(onenormest(inv, t=1))
    return 1.0 / (norm * est) if np.isfinite(est) and est > 0 else 0.0


def kinematic_position_cov(M_pr: F64, M_rr: F64 | None, dt_s: F64, motion: Motion, *, piece: int = 120,
                           margin: int = 60, M_ph: F64 | None = None) -> F64:
    """Covariance blocks ``(N, 3, 3)`` of the positions of :func:`solve_kinematic` (units of ``1 / M``).

    The position block of the inverse KKT matrix (the equality-constrained estimator's
    covariance), for the information ``M_pr`` (pseudoranges) and ``M_rr`` (range rates, or
    None). A segment longer than ``piece`` epochs is cut into pieces, each solved with
    ``margin`` epochs of its neighbours on either side (``M_ph``: the information of the epoch
    pairs, as in :func:`solve_kinematic`): less information than the whole segment, so the
    blocks are then slightly larger (conservative), never smaller. On a simulated 20-min 1 Hz
    flight with Doppler the defaults gave traces within 0.2 % (median; 3.4 % at most) of the
    whole-segment inverse at an eighth of its cost (the cost grows with ``piece + 2 margin``
    per epoch). NaN where a piece's system is singular.
    """
    n = M_pr.shape[0]
    cov = np.full((n, 3, 3), np.nan)
    for a in range(0, n, piece):
        b = min(n, a + piece)
        lo, hi = max(0, a - margin), min(n, b + margin)
        ph = None
        if M_ph is not None:
            ph = M_ph[lo:hi].copy()
            ph[0] = 0.0  # the pair ending at the piece's first epoch starts outside it
        kkt = _kkt(M_pr[lo:hi], None if M_rr is None else M_rr[lo:hi], motion_terms(motion, dt_s[lo : hi - 1]),
                   motion.n_kin, ph)
        try:
            lu = splu(kkt)
        except RuntimeError:  # exactly singular
            continue
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


def solve_kinematic(pr: EpochNormals, rr: EpochNormals | None, step_m: F64, dt_s: F64, motion: Motion,
                    ph: EpochNormals | None = None, terms: MotionTerms | None = None) -> KinematicSolution:
    """Solve one segment (module docstring).

    Parameters
    ----------
    pr, rr : EpochNormals
        Pseudorange normals (relative to the linearization points) and range-rate normals
        (absolute velocity; None: no range rates) of the segment's ``N`` epochs.
    step_m : ``(N - 1, 3)``
        ``x_nom_{t+1} - x_nom_t``, m.
    dt_s : ``(N - 1,)``
        Time steps, s.
    motion : Motion
        The motion model.
    ph : EpochNormals, optional
        Normals of rows on two consecutive positions (time-differenced carrier phase), the
        nuisance columns reduced: ``ph.M[t]`` ``(6, 6)`` and ``ph.r[t]`` ``(6,)`` on
        ``[z_{t-1}, z_t]``; row 0 is not used (the term ``z^T M z - 2 z^T r`` joins the sum).
    terms : MotionTerms, optional
        The model's terms, when they are not those of ``motion`` (the identified piecewise
        behavior of ``stls``, :func:`gnss_cli.behavior.piecewise.piecewise_terms`; ``motion``
        then only gives the state blocks, :attr:`Motion.n_kin`).

    Returns
    -------
    KinematicSolution
        NaN corrections and velocities, ``rcond = 0``, when the system is singular.
    """
    n, k = pr.M.shape[0], motion.n_kin
    terms = motion_terms(motion, dt_s) if terms is None else terms
    kkt = _kkt(pr.M, None if rr is None else rr.M, terms, k, None if ph is None else ph.M)
    r_x = pr.r.copy()
    if ph is not None and n > 1:
        r_x[:-1] += ph.r[1:, :3]
        r_x[1:] += ph.r[1:, 3:]
    g = np.zeros((k, n, 3))
    g[0] = r_x
    if k >= 2 and rr is not None:
        g[1] = rr.r
    eye3 = sp.eye(3)
    step = step_m.ravel()
    rhs = g.ravel()
    if terms.soft.shape[0]:
        rhs = rhs - sp.kron(terms.soft.T @ terms.soft_weight @ terms.soft_step, eye3) @ step
    c = -(sp.kron(terms.hard_step, eye3) @ step) if terms.hard.shape[0] else np.zeros(0)
    try:
        lu = splu(kkt)
    except RuntimeError:  # exactly singular
        nan = np.full((n, 3), np.nan)
        return KinematicSolution(nan, nan, float("nan"), 0, 0.0)
    u = lu.solve(np.concatenate([rhs, c]))[: 3 * k * n]
    z = u[: 3 * n].reshape(n, 3)
    v = u[3 * n : 6 * n].reshape(n, 3) if k >= 2 else np.zeros((n, 3))
    mis = float(pr.s.sum() - 2 * np.sum(z * pr.r) + np.einsum("ti,tij,tj->", z, pr.M, z))
    dof = int(pr.n_rows.sum() - pr.n_free.sum()) - 3 * (k * n - terms.hard.shape[0])
    if rr is not None:
        mis += float(rr.s.sum() - 2 * np.sum(v * rr.r) + np.einsum("ti,tij,tj->", v, rr.M, v))
        dof += int(rr.n_rows.sum() - rr.n_free.sum())
    if ph is not None and n > 1:
        z6 = np.hstack([z[:-1], z[1:]])
        mis += float(ph.s[1:].sum() - 2 * np.sum(z6 * ph.r[1:]) + np.einsum("ti,tij,tj->", z6, ph.M[1:], z6))
        dof += int(ph.n_rows[1:].sum() - ph.n_free[1:].sum())
    if terms.counted:
        c = terms.counted
        e = (sp.kron(terms.soft[:c], eye3) @ u + sp.kron(terms.soft_step[:c], eye3) @ step)
        mis += float(e @ (sp.kron(terms.soft_weight[:c, :c], eye3) @ e))
        dof += 3 * c
    return KinematicSolution(z, v, mis, dof, _rcond(kkt, lu))
