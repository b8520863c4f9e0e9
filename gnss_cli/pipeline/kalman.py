"""The ``kf`` method: an extended Kalman filter (and RTS smoother) on the pseudoranges, range rates and
time-differenced carrier phase.

State (ECEF, metres and seconds): position, velocity, (acceleration with ``model = "ca"``), one
receiver clock per system (m) and one clock drift common to every system (m/s: all systems
share the receiver's oscillator). Motion: constant velocity (``cv``; white acceleration of PSD
``accel_psd_m2_s3`` per axis) or constant acceleration (``ca``; white jerk of PSD
``jerk_psd_m2_s5``); each clock is a random walk (``clock_psd_m2_s``) driven by the common
drift, itself a random walk (``drift_psd_m2_s3``).

Measurements (``measurements``, :mod:`gnss_cli.pipeline.kalman_rows`: the same information as the
smoother's): every pseudorange the WLS solution used (same satellites, elevation mask, weights
and FDE exclusions), row ``[-e, 0, ..., clock one-hot, 0]``; with ``"doppler"`` every range rate
of those satellites, row ``[0, -e + Sagnac, ..., 0, 1]`` (:mod:`gnss_cli.gnss.doppler`) with the
sigmas of :func:`~gnss_cli.pipeline.velocity.doppler_sigma_m_s`; with ``"phase"`` the
time-differenced carrier phase of consecutive epochs of the smoother
(:func:`~gnss_cli.pipeline.phase_rows.phase_pair_rows`: same pairs, slip screening and sigmas), a
row on ``x(t) - x(t-1)`` plus a free clock change per system. Each kind's sigmas are scaled by the
smoother's variance factor of that kind, estimated from the data.

The phase rows by stochastic cloning: with phase the state is augmented with a copy of the
previous epoch's position (:func:`~gnss_cli.solvers.kalman.clone_transition`), the row is
``[-e_t, ..., e_{t-1}]`` on ``[x_t, ..., x_{t-1}]`` and the clock changes are eliminated exactly
(:class:`~gnss_cli.solvers.kalman.FreeRows`); the RTS smoother runs on the augmented state. It is
exact: the augmented states are a Markov chain whose measurements at ``t`` depend on state ``t``
alone, and a free clock change equals the smoother's (tying it to the filter's clocks would let
their random walk, and a receiver's millisecond clock jumps, which the phase need not share, into
the displacement). Dividing the difference by ``dt`` as a velocity is not: ``x_t - x_{t-1}`` is the
integral of the velocity over the interval, not ``dt`` times its value at ``t``.

Linearization: the pseudoranges are linearized at a nominal trajectory -- the WLS fixes,
interpolated in time where WLS has none -- with the corrections and weights evaluated there;
the filter then works on the linear model ``q - e . x_nom = -e . x + b``. Where the smoothed
(or filtered) trajectory ends more than 50 m from the nominal one, the pseudoranges are
linearized again at it and the filter rerun (at most 3 passes; with the gate, the
gate applies in one more, final pass at the last trajectory, at the epochs whose last pass
moved them less than 50 m): the neglected curvature is
``|dx|^2 / (2 rho)``, below 1e-4 m for 50 m (the corrections and weights change less).

Time: a gap longer than ``gap_s`` starts a new segment, filtered (and smoothed) on its own from
its first WLS fix; shorter gaps are bridged by the motion model. Epochs of a segment before its
first WLS fix have no kf position (they keep the WLS status). A clock jump (the second time
difference of the WLS reference clock above ``clock_reset_m``, e.g. a millisecond reset of a
steered receiver clock) adds a large process noise to every clock at that epoch.

Gate: the smoother's (:func:`~gnss_cli.pipeline.kalman_rows.gate_threshold`: the two-sided normal
quantile of ``integrity_pfa``, off with ``integrity = "off"``), on the filter's innovations
(:func:`~gnss_cli.solvers.kalman.kalman_update`). A pseudorange or range rate whose innovation
exceeds it, in sigmas of the predicted innovation, is not used at that epoch, unless more than
half of the epoch's rows of its kind exceed it (the motion model failed, not the data). A phase
difference: the largest whose innovation predicted from the prior and the epoch's other phase
differences exceeds it is not used, one at a time (:func:`~gnss_cli.solvers.kalman.free_update`).
``n_sat`` and the residuals count only the pseudoranges
used. What differs from the smoother: a filter tests each row against what the data before it
(and the motion model) predict, with the variance of that prediction -- the smoother's residuals
come from a fit to every epoch, the row itself included, and are not divided by their
redundancy; both statistics are N(0, 1) when the model holds, so the threshold keeps its
false-alarm probability. The filter's decision at an epoch is final (a later epoch cannot bring
a row back, the smoother's passes can), and the prediction of a phase difference from the motion
model alone (metres at 1 s) could not see a slip of one cycle, hence the epoch's other differences.

Per epoch: ``ok`` after an update with at least one pseudorange, ``predicted`` when the epoch
had no usable measurement (motion model, and smoother, only). ``cov_m2`` is the smoothed
(filtered with ``smoother = "none"``) covariance of position and clocks; the DOP columns are that
covariance divided by the median variance of the run's used pseudoranges, with their factor (so
they are the multi-epoch DOP of the filter, for a typical satellite's variance), ``gdop_vel`` the
velocity and drift covariance divided by ``doppler_sigma_m_s^2``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from gnss_cli.config import ProcessingConfig
from gnss_cli.gnss.doppler import range_rate_system
from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic
from gnss_cli.gnss.range_model import linearize
from gnss_cli.pipeline.kalman_rows import (PhaseRows, filter_phase_rows, gate_threshold, kinds_config,
                                           measurement_kinds, variance_factors)
from gnss_cli.pipeline.results import EpochData, EpochStatus, MethodSolution, as_wls_used
from gnss_cli.pipeline.velocity import doppler_sigma_m_s, solve_velocity
from gnss_cli.solvers.dop import dop_from_cov
from gnss_cli.solvers.kalman import FreeRows, clone_prior, clone_transition, kalman_filter, rts_smooth

F64 = NDArray[np.float64]

__all__ = ["run_kalman", "transition", "linearized_measurements", "nominal_trajectory"]

_RELINEARIZE_M = 50.0
_MAX_PASSES = 3
_CLOCK_RESET_VAR_M2 = 1e12
_ABSENT_CLOCK_VAR_M2 = 1e8
_BLOCK = 2048  # epochs per linearization block
_CLONED = np.arange(3)  # with phase: the previous epoch's position rides along in the state


@dataclass(frozen=True)
class _Layout:
    """Indices of the state vector ``[pos, vel, (acc), clocks (k), drift]``."""

    n_kin: int  # 2 (cv) or 3 (ca) blocks of 3
    k: int

    @property
    def m(self) -> int:
        return 3 * self.n_kin + self.k + 1

    @property
    def clocks(self) -> NDArray[np.intp]:
        return 3 * self.n_kin + np.arange(self.k)

    @property
    def drift(self) -> int:
        return self.m - 1


def transition(dt_s: float, layout_n_kin: int, k: int, config: ProcessingConfig) -> tuple[F64, F64]:
    """Transition ``F`` and process noise ``Q`` over ``dt_s`` (s) of the state in the module docstring.

    Examples
    --------
    >>> from gnss_cli.config import ProcessingConfig
    >>> F, Q = transition(2.0, 2, 1, ProcessingConfig())
    >>> float(F[0, 3]), float(F[6, 7]), float(Q[0, 0] / Q[3, 3])  # x += 2 v_x, clock += 2 drift; (S 8/3) / (S 2)
    (2.0, 2.0, 1.3333333333333333)
    """
    kc = config.kalman
    lay = _Layout(layout_n_kin, k)
    F = np.eye(lay.m)
    Q = np.zeros((lay.m, lay.m))
    if layout_n_kin == 2:
        f1 = np.array([[1.0, dt_s], [0.0, 1.0]])
        q1 = kc.accel_psd_m2_s3 * np.array([[dt_s**3 / 3, dt_s**2 / 2], [dt_s**2 / 2, dt_s]])
    else:
        f1 = np.array([[1.0, dt_s, dt_s**2 / 2], [0.0, 1.0, dt_s], [0.0, 0.0, 1.0]])
        q1 = kc.jerk_psd_m2_s5 * np.array([[dt_s**5 / 20, dt_s**4 / 8, dt_s**3 / 6],
                                           [dt_s**4 / 8, dt_s**3 / 3, dt_s**2 / 2],
                                           [dt_s**3 / 6, dt_s**2 / 2, dt_s]])
    kin = 3 * layout_n_kin
    F[:kin, :kin] = np.kron(f1, np.eye(3))
    Q[:kin, :kin] = np.kron(q1, np.eye(3))
    c, d = lay.clocks, lay.drift
    F[c, d] = dt_s
    sd = kc.drift_psd_m2_s3
    Q[np.ix_(c, c)] = sd * dt_s**3 / 3 + np.eye(k) * kc.clock_psd_m2_s * dt_s
    Q[c, d] = Q[d, c] = sd * dt_s**2 / 2
    Q[d, d] = sd * dt_s
    return F, Q


@dataclass
class Measurements:
    """Linearized pseudoranges and range rates of every epoch (``(T, n)`` arrays), configured variances
    (the filter scales them by ``factors``: pseudoranges, range rates, phase pairs), phase pairs."""

    unit: F64  # line of sight, (T, n, 3)
    y_pr: F64  # q - e . x_nom: equals -e . x + b
    var_pr: F64
    used: NDArray[np.bool_]
    iono_m: F64  # (T, n) modelled ionospheric delay in y_pr's computed value, m
    H_rr: F64 | None = None  # (T, n, 4): [v, d]
    y_rr: F64 | None = None
    var_rr: F64 | None = None
    used_rr: NDArray[np.bool_] | None = None
    phase: PhaseRows | None = None
    factors: tuple[float, float, float] = (1.0, 1.0, 1.0)


def linearized_measurements(data: EpochData, nominal: F64, config: ProcessingConfig) -> Measurements:
    """Linearize every epoch's pseudoranges (and range rates) at the nominal positions."""
    T, n = data.time_gps_s.size, data.sv.size
    unit, y, var, iono = np.zeros((T, n, 3)), np.zeros((T, n)), np.ones((T, n)), np.zeros((T, n))
    used = np.zeros((T, n), dtype=bool)
    zero_clock = np.zeros((1, len(data.systems)))
    for start in range(0, T, _BLOCK):
        rows = np.arange(start, min(T, start + _BLOCK))
        lin = linearize(data, rows, nominal[rows], np.repeat(zero_clock, rows.size, axis=0), config)
        mask = lin.mask[:, :n]
        e = lin.unit[:, :n]
        unit[rows] = e
        y[rows] = np.where(mask, lin.q[:, :n] - np.einsum("tnk,tk->tn", e, nominal[rows]), 0.0)
        var[rows] = np.where(mask, lin.var_m2[:, :n], 1.0)
        iono[rows] = np.where(mask, lin.iono_m[:, :n], 0.0)
        used[rows] = mask
    out = Measurements(unit, y, var, used, iono)
    if config.uses("doppler") and data.range_rate_m_s is not None and data.sat_vel_ecef_m_s is not None:
        H, yr = range_rate_system(data.sat_ecef_m, data.sat_vel_ecef_m_s, data.sat_clock_drift_s_s,
                                  data.range_rate_m_s, nominal)
        sigma = doppler_sigma_m_s(np.where(used, np.sqrt(var), np.nan), config)
        out.used_rr = used & np.isfinite(yr) & np.isfinite(sigma)
        out.H_rr, out.y_rr, out.var_rr = H, np.where(out.used_rr, yr, 0.0), np.where(out.used_rr, sigma**2, 1.0)
    return out


def _rows(meas: Measurements, t: int, lay: _Layout, sysidx: NDArray[np.int64], m: int,
          first: bool) -> tuple[F64, F64, F64, NDArray[np.int64], FreeRows | None]:
    """Rows, values, variances (with their factors) and kinds (0 pseudorange, 1 range rate) of epoch
    ``t`` for a state of ``m`` components (with phase: the cloned position last), and its phase rows
    (none at the ``first`` epoch of a segment: its clone is itself)."""
    i = np.flatnonzero(meas.used[t])
    H = np.zeros((i.size, m))
    H[:, :3] = -meas.unit[t, i]
    H[np.arange(i.size), lay.clocks[sysidx[i]]] = 1.0
    y, r = meas.y_pr[t, i], meas.var_pr[t, i] * meas.factors[0]
    kind = np.zeros(i.size, dtype=np.int64)
    if meas.used_rr is not None:
        j = np.flatnonzero(meas.used_rr[t])
        Hd = np.zeros((j.size, m))
        Hd[:, 3:6] = meas.H_rr[t, j, :3]
        Hd[:, lay.drift] = 1.0
        H, y = np.vstack([H, Hd]), np.concatenate([y, meas.y_rr[t, j]])
        r, kind = np.concatenate([r, meas.var_rr[t, j] * meas.factors[1]]), np.r_[kind, np.ones(j.size, dtype=np.int64)]
    ph = meas.phase
    if ph is None or first:
        return H, y, r, kind, None
    j = np.flatnonzero(ph.used[t])
    Hp = np.zeros((j.size, m))
    Hp[:, :3] = ph.H6[t, j, 3:]
    Hp[:, lay.m + _CLONED] = ph.H6[t, j, :3]
    G = (sysidx[j, None] == np.arange(lay.k)).astype(np.float64)
    return H, y, r, kind, FreeRows(Hp, ph.y[t, j], ph.var_m2[t, j] * meas.factors[2], G)


def _segments(t: F64, has_fix: NDArray[np.bool_], gap_s: float) -> list[NDArray[np.intp]]:
    """Epoch indices of each segment (split at gaps longer than ``gap_s``), from its first fix on."""
    cuts = np.flatnonzero(np.diff(t) > gap_s) + 1
    out = []
    for seg in np.split(np.arange(t.size), cuts):
        fixed = np.flatnonzero(has_fix[seg])
        if fixed.size:
            out.append(seg[fixed[0]:])
    return out


def _clock_jumps(t: F64, clock_m: F64, threshold_m: float) -> NDArray[np.bool_]:
    """Epochs whose WLS reference clock jumps: second time difference above ``threshold_m``."""
    jump = np.zeros(t.size, dtype=bool)
    ok = np.flatnonzero(np.isfinite(clock_m))
    if ok.size >= 3:
        rate = np.diff(clock_m[ok]) / np.diff(t[ok])
        second = np.abs(np.diff(rate) * np.diff(t[ok])[1:])
        jump[ok[2:][second > threshold_m]] = True
    return jump


def _run_segment(seg: NDArray[np.intp], data: EpochData, meas: Measurements, init: dict[str, F64],
                 lay: _Layout, jumps: NDArray[np.bool_], config: ProcessingConfig,
                 gate: NDArray[np.float64] | None = None) -> tuple[F64, F64]:
    """Filter (and smooth) one segment; returns the state means ``(s, m)`` and covariances.
    Pseudoranges the innovation gate rejected are taken out of ``meas.used``."""
    t = data.time_gps_s[seg]
    F = np.zeros((seg.size, lay.m, lay.m))
    Q = np.zeros_like(F)
    steps: dict[float, tuple[F64, F64]] = {}  # one transition per distinct interval
    for j in range(1, seg.size):
        dt = round(float(t[j] - t[j - 1]), 9)
        if dt not in steps:
            steps[dt] = transition(dt, lay.n_kin, lay.k, config)
        F[j], Q[j] = steps[dt]
        if jumps[seg[j]]:
            Q[j][lay.clocks, lay.clocks] += _CLOCK_RESET_VAR_M2
    sysidx = data.clock_index
    m0, P0 = _prior(init, int(seg[0]), lay, config)
    if meas.phase is not None:
        F, Q = clone_transition(F, Q, _CLONED)
        m0, P0 = clone_prior(m0, P0, _CLONED)
    H, y, r, kind, free = zip(*(_rows(meas, int(i), lay, sysidx, m0.size, j == 0) for j, i in enumerate(seg)))
    gates = None if gate is None else [float(g) if np.isfinite(g) else None for g in gate[seg]]
    res = kalman_filter(m0, P0, F, Q, H, y, r, gates, groups=kind, free=None if meas.phase is None else free)
    for i, nu in zip(seg, res.innovations):
        rows = np.flatnonzero(meas.used[i])
        meas.used[i, rows[np.isnan(nu[: rows.size])]] = False
    x, P = rts_smooth(res, F) if config.kalman.output == "smoothed" else (res.x, res.P)
    return x[:, :lay.m], P[:, :lay.m, :lay.m]


def _prior(init: dict[str, F64], t0: int, lay: _Layout, config: ProcessingConfig) -> tuple[F64, F64]:
    """Mean and covariance of the first state of a segment: the WLS fix and clocks with 4 x their
    covariance (a clock of a system without satellites there: 10 km), the Doppler velocity and
    drift with 100 x ``doppler_sigma_m_s^2`` where there is one (range rates used), else zero with the
    initial sigmas."""
    m0 = np.zeros(lay.m)
    P0 = np.zeros((lay.m, lay.m))
    pc = np.r_[0:3, lay.clocks]
    clocks = init["clocks"][t0]
    m0[:3], m0[lay.clocks] = init["x"][t0], np.nan_to_num(clocks)
    cov = 4.0 * init["cov"][t0]
    absent = 3 + np.flatnonzero(~np.isfinite(init["tdops"][t0]))
    cov[absent, :] = 0.0
    cov[:, absent] = 0.0
    cov[absent, absent] = _ABSENT_CLOCK_VAR_M2
    P0[np.ix_(pc, pc)] = np.where(np.isfinite(cov), cov, 0.0) + np.diag(np.where(np.isfinite(np.diag(cov)), 0.0, 100.0))
    v, d = init["vel"][t0], init["drift"][t0]
    have_v = bool(np.isfinite(v).all() and np.isfinite(d))
    kc = config.kalman
    m0[3:6] = v if have_v else 0.0
    m0[lay.drift] = d if have_v else 0.0
    vd = np.r_[3:6, lay.drift]
    P0[vd, vd] = (config.doppler_sigma_m_s**2 * 100.0 if have_v else
                  np.array([kc.initial_velocity_sigma_m_s**2] * 3 + [kc.initial_drift_sigma_m_s**2]))
    if lay.n_kin == 3:
        P0[6:9, 6:9] = 100.0 * np.eye(3)  # (10 m/s^2)^2
    return m0, P0


def nominal_trajectory(t: F64, x: F64) -> F64:
    """Positions ``x`` with the missing epochs interpolated in time (nearest at the ends)."""
    ok = np.isfinite(x).all(axis=1)
    return np.stack([np.interp(t, t[ok], x[ok, i]) for i in range(3)], axis=1)


def run_kalman(data: EpochData, wls: MethodSolution, config: ProcessingConfig, *,
               measurements: frozenset[str] | None = None,
               factors: tuple[float, float, float] | None = None) -> MethodSolution:
    """The ``kf`` rows: filter (and smooth) every segment with the WLS solution's satellites.

    Parameters
    ----------
    data : EpochData
        The prepared epochs (with ``"phase"``: read with their carrier phase).
    wls : MethodSolution
        The WLS solution: nominal trajectory, initial state, FDE exclusions, variance factors.
    config : ProcessingConfig
        ``[kalman]`` settings, weights, corrections, ``doppler_sigma_m_s``, ``phase_sigma_m`` and
        ``phase_slip_m``, ``integrity`` and ``integrity_pfa`` (the gate).
    measurements : frozenset of str, optional
        The kinds used, a subset of ``{"pseudorange", "doppler", "phase"}`` with ``"pseudorange"``
        (those the file lacks are not used); None: ``[processing] measurements``
        (:func:`~gnss_cli.pipeline.kalman_rows.measurement_kinds`).
    factors : tuple of 3 float, optional
        Variance factors of pseudoranges, range rates and phase pairs, when estimated beforehand;
        None: estimated from ``data`` as the smoother does
        (:func:`~gnss_cli.pipeline.kalman_rows.variance_factors`).

    Returns
    -------
    MethodSolution
        Method ``kf``; epochs before a segment's first WLS fix keep the WLS status, no position.

    Raises
    ------
    ConfigError
        ``measurements`` has an unknown kind or lacks ``"pseudorange"``.
    """
    kinds = measurement_kinds(data, config, measurements)
    data = as_wls_used(data, wls)  # its satellites and weights
    factors = variance_factors(data, wls, config) if factors is None else factors
    rows_config = kinds_config(config, kinds)
    T, k = data.time_gps_s.size, len(data.systems)
    lay = _Layout(3 if config.kalman.model == "ca" else 2, k)
    has_fix = np.isfinite(wls.x_ecef_m).all(axis=1)
    clocks = wls.clocks_m
    vel = solve_velocity(data, wls.x_ecef_m, wls.sigma_m if wls.sigma_m is not None else np.ones(data.usable.shape),
                         config) if "doppler" in kinds else None  # without range rates the prior has none either
    tdops = wls.tdops if wls.tdops is not None else np.zeros((T, k))
    init = {"x": wls.x_ecef_m, "clocks": clocks, "cov": wls.cov_m2, "tdops": tdops,
            "vel": vel.vel_ecef_m_s if vel else np.full((T, 3), np.nan),
            "drift": vel.clock_drift_m_s if vel else np.full(T, np.nan)}
    segments = _segments(data.time_gps_s, has_fix, config.kalman.gap_s)
    jumps = _clock_jumps(data.time_gps_s, clocks[:, 0], config.kalman.clock_reset_m)
    nominal = nominal_trajectory(data.time_gps_s, wls.x_ecef_m) if has_fix.any() else np.zeros((T, 3))
    x = np.full((T, lay.m), np.nan)
    P = np.full((T, lay.m, lay.m), np.nan)

    def one_pass(gate: F64 | None) -> Measurements:
        meas = linearized_measurements(data, nominal, rows_config)
        meas.phase = filter_phase_rows(data, meas, nominal, rows_config) if "phase" in kinds else None
        meas.factors = factors
        for seg in segments:
            x[seg], P[seg] = _run_segment(seg, data, meas, init, lay, jumps, config, gate)
        return meas

    passes = 0
    moved = np.zeros(T)
    for passes in range(1, _MAX_PASSES + 1):
        meas = one_pass(None)
        have = np.isfinite(x[:, 0])
        moved[have] = np.linalg.norm(x[have, :3] - nominal[have], axis=1)
        nominal[have] = x[have, :3]
        if moved.max() <= _RELINEARIZE_M:
            break
    gate = gate_threshold(config)
    if gate is not None:  # only where the linearization has settled (else it rejects good data)
        meas = one_pass(np.where(moved <= _RELINEARIZE_M, gate, np.nan))
        passes += 1
    return _solution(data, wls, meas, x, P, lay, passes, config)


def _solution(data: EpochData, wls: MethodSolution, meas: Measurements, x: F64, P: F64, lay: _Layout,
              passes: int, config: ProcessingConfig) -> MethodSolution:
    """Build the ``kf`` :class:`MethodSolution` from the state means and covariances."""
    k = lay.k
    have = np.isfinite(x[:, 0])
    n_sat = np.where(have, meas.used.sum(axis=1), 0).astype(np.int64)
    status = np.where(have, np.where(n_sat > 0, EpochStatus.OK.value, EpochStatus.PREDICTED.value), wls.status)
    keep = np.r_[0:3, lay.clocks]
    cov = P[:, keep][:, :, keep]
    sysidx = data.clock_index
    clocks = x[:, lay.clocks]
    predicted = -np.einsum("tnk,tk->tn", meas.unit, x[:, :3]) + np.take_along_axis(clocks, np.broadcast_to(sysidx, meas.used.shape), 1)
    residuals = np.where(meas.used & have[:, None], meas.y_pr - predicted, np.nan)
    sigma = np.where(meas.used & have[:, None], np.sqrt(meas.var_pr), np.nan)
    var0 = float(np.nanmedian(sigma**2)) * meas.factors[0] if np.isfinite(sigma).any() else 1.0
    lat, lon, _ = ecef2geodetic(np.where(have[:, None], x[:, :3], 1.0))
    rot = ecef2enu_rotation(lat, lon)
    q = np.where(have[:, None, None], cov / var0, np.eye(3 + k))
    dop = dop_from_cov(q, rot)
    tdops = np.sqrt(np.clip(q[:, 3 + np.arange(k), 3 + np.arange(k)], 0.0, None))

    def masked(v: F64) -> F64:
        return np.where(have, v, np.nan)

    vd = np.r_[3:6, lay.drift]
    gdop_vel = np.sqrt(np.clip(np.trace(P[:, vd][:, :, vd], axis1=1, axis2=2), 0.0, None)) / config.doppler_sigma_m_s
    return MethodSolution(
        method="kf", x_ecef_m=np.where(have[:, None], x[:, :3], np.nan), clocks_m=clocks,
        n_sat=n_sat, gdop=masked(dop.gdop), pdop=masked(dop.pdop), hdop=masked(dop.hdop), vdop=masked(dop.vdop),
        tdop=masked(dop.tdop), tdops=np.where(have[:, None], tdops, np.nan), gdop_paper=None, cov_m2=cov,
        status=status.astype(wls.status.dtype), iterations=np.where(have, passes, 0).astype(np.int64),
        residuals_m=residuals, excluded=wls.excluded, sigma_m=sigma,
        vel_ecef_m_s=x[:, 3:6], clock_drift_m_s=x[:, lay.drift], gdop_vel=masked(gdop_vel),
    )
