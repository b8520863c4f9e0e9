"""Several epochs at once in the measurement domain (DESIGN.md section 6): pseudoranges and range rates
of every epoch of a window, the trajectory constrained to a behavior.

Over a window of ``N`` epochs the positions are ``x_t = origin + O_t theta`` with ``O`` a basis
of the behavior of a shared kernel ``r(z) I_3`` (:func:`~gnss_cli.behavior.multi_epoch.shared_behavior_bases`;
such a basis is the same in every Cartesian frame, so it is used in ECEF directly); the unknowns
are ``theta`` and one clock per epoch and system (and, with Doppler, one clock drift per epoch).
The observations are every pseudorange the WLS solution used (same satellites, weights and
FDE exclusions: an excluded satellite stays excluded) and, when the file has Doppler, every
range rate of those satellites (rows ``e . v_t + d_t``, ``v_t = V_t theta`` the time derivative
of the basis, :func:`~gnss_cli.behavior.window_solve.velocity_operator`). Epochs with 1-3
satellites are included: they constrain what their rows can (two satellites of one system
already give one direction); the behavior supplies the rest.

Gauss-Newton: the rows are linearized at the current trajectory (first the WLS fixes,
interpolated in time where an epoch has none), every window is solved
(:func:`~gnss_cli.behavior.window_solve.solve_windows`), each epoch takes the estimate of the
window whose centre is nearest, and the rows are linearized again until no epoch moves more
than 1 mm (at most :data:`MAX_ITERATIONS` passes).

Weights: the configured sigmas set their shape; the balance between pseudoranges and range
rates comes from the data: each is scaled by its variance factor estimated from the epochs
solved one at a time (free position, velocity, clocks and drift: the misfit over its degrees of
freedom, which does not depend on the behavior).

Model test: a window's misfit ``m`` (``f`` degrees of freedom) against the misfit ``m_0`` of its
epochs solved one at a time (``f_0``): with the variance factors applied, ``m - m_0`` is
chi-square with ``f - f_0`` degrees of freedom when the behavior holds. Each epoch takes the
longest window of ``lengths`` (default :data:`WINDOW_LADDER`) whose window supplying it passes at
:data:`WINDOW_TEST_P`; an epoch whose shortest window fails keeps that window's estimate
(``WindowRun.window`` negative).

This is the window solver for fixed shared kernels (``(z-1)^3 I`` and the like), a library
function: measured on the simulated flights of ``benchmarks/kinematic_vs_kf.py`` (seeds 11-15,
ratio of the mean 3D RMS to the truth-tuned KF+RTS on the fixes), the ``(z-1)^3 I`` kernel with
Doppler reaches 0.91 (``--errors noise``) and 0.97 (``all``) with the ladder against 1.63 and 1.36
in fixed 15-epoch windows, without Doppler 1.27 and 1.09 -- all behind the kinematic kernel of
:mod:`gnss_cli.pipeline.doppler_smoothing` (0.31 and 0.77) and, without Doppler, behind the
identified kernel on the fixes (1.06 and 1.02), which the command line therefore uses.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from gnss_cli.behavior.multi_epoch import shared_behavior_bases
from gnss_cli.behavior.window_solve import EpochNormals, free_misfit, reduce_epochs, solve_windows, velocity_operator
from gnss_cli.behavior.windows import segments, windows
from gnss_cli.config import ProcessingConfig
from gnss_cli.pipeline.kalman import linearized_measurements, nominal_trajectory
from gnss_cli.pipeline.results import EpochData, EpochStatus, MethodSolution

__all__ = ["WindowRun", "solve_in_windows", "MAX_ITERATIONS", "WINDOW_LADDER", "WINDOW_TEST_P"]

F64 = NDArray[np.float64]

MAX_ITERATIONS = 4
#: Window lengths (epochs) tried for each epoch, shortest first.
WINDOW_LADDER = (7, 11, 15, 21, 31, 45, 61)
#: False-alarm probability of the F test of a window's behavior.
WINDOW_TEST_P = 1e-3
_CONVERGED_M = 1e-3


@dataclass(frozen=True, slots=True)
class WindowRun:
    """Positions and velocities of the measurement-domain window solution.

    Attributes
    ----------
    x_ecef_m, vel_ecef_m_s : ``(T, 3)`` (NaN where not solved).
    window : ``(T,)`` length of the window that supplied each epoch (0: none).
    n_sat : ``(T,)`` pseudoranges of each epoch in the solve.
    iterations : Gauss-Newton passes.
    factors : variance factors of the pseudoranges and the range rates.
    dop_windows : (epochs, ECEF basis, owned epochs) of each supplying window, for the multi-epoch DOP.
    """

    x_ecef_m: F64
    vel_ecef_m_s: F64
    window: NDArray[np.int64]
    n_sat: NDArray[np.int64]
    iterations: int
    factors: tuple[float, float]
    dop_windows: list[tuple[NDArray[np.intp], F64, NDArray[np.intp]]]


@dataclass(slots=True)
class _Level:
    """All windows of one length: epochs ``spans (B, N)``, the epochs each supplies, basis, velocity operator."""

    length: int
    spans: NDArray[np.intp]
    owned: list[NDArray[np.intp]]
    basis: F64
    vel: F64


def _normals(data: EpochData, nominal: F64, config: ProcessingConfig,
             factors: tuple[float, float]) -> tuple[EpochNormals, EpochNormals | None, NDArray[np.int64]]:
    """Clock-reduced pseudorange and range-rate normals of every epoch at ``nominal``."""
    meas = linearized_measurements(data, nominal, config)
    k = len(data.systems)
    sysidx = data.system_index if data.system_index is not None else np.zeros(data.sv.size, dtype=np.int64)
    onehot = np.broadcast_to((sysidx[:, None] == np.arange(k)).astype(np.float64), (*meas.used.shape, k))
    q = meas.y_pr + np.einsum("tni,ti->tn", meas.unit, nominal)  # pseudorange minus its value at nominal
    pr = reduce_epochs(-meas.unit, np.where(meas.used, 1.0 / meas.var_pr, 0.0) / factors[0], q, onehot)
    rr = None
    if meas.used_rr is not None:
        w_rr = np.where(meas.used_rr, 1.0 / meas.var_rr, 0.0) / factors[1]
        rr = reduce_epochs(meas.H_rr[..., :3], w_rr, meas.y_rr)
    return pr, rr, meas.used.sum(axis=1)


def _variance_factors(pr: EpochNormals, rr: EpochNormals | None) -> tuple[float, float]:
    """Misfit per degree of freedom of the epochs solved alone, pseudoranges and range rates."""
    out = []
    for nrm in (pr, rr):
        if nrm is None:
            out.append(1.0)
            continue
        mis, rank = free_misfit(nrm)
        dof = nrm.n_rows - nrm.n_free - rank
        good = dof > 0
        total = float(dof[good].sum())
        out.append(float(mis[good].sum()) / total if total > 0 and mis[good].sum() > 0 else 1.0)
    return out[0], out[1]


def _levels(segs: list[NDArray[np.intp]], lengths: tuple[int, ...], coef: F64, dt_s: float) -> list[list[_Level]]:
    """For every window length: the windows of every segment, grouped by their actual length."""
    out = []
    for length in lengths:
        groups: dict[int, tuple[list[NDArray[np.intp]], list[NDArray[np.intp]]]] = {}
        for seg in segs:
            bounds, owner = windows(seg.size, length, max(1, length // 4))
            for wi, (a, b) in enumerate(bounds):
                spans, owned = groups.setdefault(b - a, ([], []))
                spans.append(seg[a:b])
                owned.append(np.flatnonzero(owner == wi) - a)
        level = []
        for n_t, (spans, owned) in groups.items():
            if n_t < coef.size:
                continue
            basis = shared_behavior_bases(coef[None, :], n_t, 3)[0]
            assert basis is not None
            stacked = np.broadcast_to(basis, (len(spans), *basis.shape))
            level.append(_Level(length, np.stack(spans), owned, stacked, velocity_operator(stacked, dt_s)))
        out.append(level)
    return out


def _free(pr: EpochNormals, rr: EpochNormals | None) -> tuple[F64, NDArray[np.int64]]:
    """Misfit and degrees of freedom of each epoch solved alone (free position, velocity, clocks, drift)."""
    mis, rank = free_misfit(pr)
    dof = pr.n_rows - pr.n_free - rank
    if rr is not None:
        mis_r, rank_r = free_misfit(rr)
        mis, dof = mis + mis_r, dof + rr.n_rows - rr.n_free - rank_r
    return mis, dof


def _solve_levels(levels: list[list[_Level]], nominal: F64, pr: EpochNormals, rr: EpochNormals | None,
                  test_p: float) -> tuple[F64, F64, NDArray[np.int64], list[tuple[NDArray[np.intp], F64, NDArray[np.intp]]]]:
    """Every window of every length; each epoch takes its longest window that passes the behavior test."""
    T = nominal.shape[0]
    x, v = np.full((T, 3), np.nan), np.full((T, 3), np.nan)
    chosen = np.zeros(T, dtype=np.int64)
    dop: dict[int, tuple[NDArray[np.intp], F64, NDArray[np.intp]]] = {}
    free_mis, free_dof = _free(pr, rr)
    for level in levels:
        for grp in level:
            origin = nominal[grp.spans[:, grp.spans.shape[1] // 2]]
            offset = origin[:, None, :] - nominal[grp.spans]
            sol = solve_windows(grp.basis, grp.spans, offset, pr, grp.vel if rr is not None else None, rr)
            extra_mis = sol.misfit - free_mis[grp.spans].sum(axis=1)
            extra_dof = sol.dof - free_dof[grp.spans].sum(axis=1)
            passed = sol.ok & ((extra_dof <= 0) | (extra_mis <= stats.chi2.isf(test_p, np.maximum(extra_dof, 1))))
            for b in np.flatnonzero(passed | (sol.ok & (grp.length == levels[0][0].length))):
                own = grp.owned[b]
                ep = grp.spans[b, own]
                upgrade = passed[b] | (chosen[ep] == 0)
                ep, own = ep[upgrade], own[upgrade]
                x[ep] = origin[b] + grp.basis[b, own] @ sol.theta[b]
                v[ep] = grp.vel[b, own] @ sol.theta[b]
                chosen[ep] = grp.length if passed[b] else -grp.length
                for e in ep:
                    dop[int(e)] = (grp.spans[b], grp.basis[b], np.array([e]))
    return x, v, chosen, list(dop.values())


def solve_in_windows(data: EpochData, wls: MethodSolution, config: ProcessingConfig, coef: F64,
                     lengths: tuple[int, ...] = WINDOW_LADDER, *, gap_factor: float = 1.5,
                     test_p: float = WINDOW_TEST_P) -> WindowRun | None:
    """Measurement-domain solution over windows of the fixed shared kernel ``coef`` (module docstring).

    Parameters
    ----------
    data : EpochData
        Prepared epochs (range rates used when present and ``[kalman] doppler``).
    wls : MethodSolution
        WLS solution: starting trajectory and FDE exclusions.
    config : ProcessingConfig
        Weights, corrections, ``doppler_sigma_m_s``.
    coef : ``(l + 1,)``
        Shared kernel ``r(z) = coef[0] + ... + coef[l] z^l`` (``coef[l] != 0``).
    lengths : window lengths (epochs) tried, shortest first.
    gap_factor : float
        A step longer than ``gap_factor`` times the median step splits a segment.
    test_p : float
        False-alarm probability of the behavior test of a window.

    Returns
    -------
    WindowRun, or None when WLS solved no epoch.
    """
    if wls.excluded is not None:
        data = replace(data, usable=data.usable & ~wls.excluded)
    t = data.time_gps_s
    fix = (wls.status == EpochStatus.OK.value) & np.isfinite(wls.x_ecef_m).all(axis=1)
    if not fix.any():
        return None
    segs = [s for s in segments(t, data.usable.any(axis=1), gap_factor) if s.size >= coef.size and fix[s].any()]
    dt = np.diff(t)
    dt_s = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 1.0
    levels = _levels(segs, tuple(sorted(lengths)), np.asarray(coef, dtype=np.float64), dt_s)
    nominal = nominal_trajectory(t, np.where(fix[:, None], wls.x_ecef_m, np.nan))
    pr, rr, n_sat = _normals(data, nominal, config, (1.0, 1.0))
    factors = _variance_factors(pr, rr)
    for it in range(1, MAX_ITERATIONS + 1):
        pr, rr, n_sat = _normals(data, nominal, config, factors)
        x, v, chosen, dop = _solve_levels(levels, nominal, pr, rr, test_p)
        have = np.isfinite(x).all(axis=1)
        moved = float(np.max(np.linalg.norm(x[have] - nominal[have], axis=1), initial=0.0))
        nominal[have] = x[have]
        if moved < _CONVERGED_M:
            break
    return WindowRun(x, v, chosen, n_sat.astype(np.int64), it, factors, dop)

