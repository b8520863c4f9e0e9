"""The ``smoother`` method: the fixed-model batch smoother of whole segments in the measurement domain
(DESIGN.md section 6). Nothing is identified: the motion model is given.

Unknowns, per segment of uniformly sampled epochs with at least one usable satellite and one
WLS fix: the trajectory under the motion (:mod:`gnss_cli.behavior.kinematic_solve`):
``quadrature`` (``x_{t+1} - x_t`` equals ``dt`` times the lag-L interpolation of the
velocities, exact for velocities polynomial of degree L, with a weak jerk prior), ``cv`` /
``ca`` (constant velocity / acceleration with white acceleration / jerk of the ``[kalman]``
PSDs: the kf's motion, solved as one batch) or ``static`` (one position); one clock per epoch
and system and one clock drift per epoch. Observations (``measurements``, a subset of
:data:`KINDS`): every pseudorange the WLS solution used (its satellites, elevation mask, weights
and FDE exclusions); with ``"doppler"`` the range rates of those satellites; with ``"phase"``
the time-differenced carrier phase of consecutive epochs (:mod:`gnss_cli.pipeline.phase_rows`;
with quadrature lag 3 and Doppler, on the Yamatogawa walk 2.71 -> 2.48 m 3D RMS, on the urban
tst2 set 2.52 -> 1.37 m). A segment bridges missed epochs: a step of up to
:data:`MAX_STEP_INTERVALS` sampling intervals stays inside it (the quadrature rule at the epochs'
own times, the phase pair across the step); the Yamatogawa walk's first epoch, two seconds
before the rest, was a segment of one before (its WLS fix, 1.5 m off: 0.371 -> 0.358 m
horizontal RMS with phase, ``benchmarks/multi_epoch_fair.py``). An epoch alone between two longer gaps is not smoothed: it keeps its
WLS fix with the status ``fallback_wls``. Epochs with 1-3 satellites are included (such an epoch is ``ok`` and
``n_sat`` says how many pseudoranges it had; with a single satellite its clock absorbs the
pseudorange and the position comes from the motion and its neighbours). Without Doppler the
velocities come from the motion model alone (and the phase pairs, where given).

Measured (``benchmarks/bench_smoother.py``, 3D RMS, m, default processing; simulated 1 Hz flights
with white noise, mean of three seeds / the Yamatogawa walk / tst2 on its 157 truth epochs):

- pseudoranges alone: quadrature 1.90 / 2.98 / 4.38 (4.37 on the 142 epochs WLS solves; WLS 3.15 /
  3.07 / 5.14), cv and ca within 2 % of it; static 2.70 on tst2 (and useless on the moving sets:
  nothing tests the motion);
- with Doppler: quadrature 0.36 / 2.72 / 2.83, ca 0.45 / 2.70 / 3.10, cv 1.23 / 2.89 / 3.51. The
  quadrature rule ties each step to the velocities exactly; cv with the kf's default acceleration
  PSD of 10 m^2/s^3 lets a 1 s step deviate by ~0.9 m from the mean of its two velocities, which
  the variance factors (pseudorange weights x13 on the flights) make loose (on the flights of an
  earlier run a PSD of 0.1 gave 0.51, ca with a jerk PSD of 1 or less 0.45 = the quadrature; the
  equal-information benchmark, ``benchmarks/multi_epoch_fair.py``, chooses these PSDs on training
  seeds);
- with phase every motion but static gives 2.48-2.49 / 1.67 (the phase pairs fix the shape).

Weights: the configured pseudorange, Doppler (and phase) sigmas give their shape; each kind is scaled by
a variance factor estimated from the data -- the misfit per degree of freedom of the epochs
solved one at a time (free position, velocity, clocks, drift), which does not depend on the
motion -- so the balance between the kinds is not tuned per data set.

Fault exclusion, as the snapshot solution's (``integrity`` not ``"off"``): a pseudorange or range
rate whose standardized residual exceeds the two-sided normal quantile of ``integrity_pfa``
(3.29 for 1e-3) is excluded -- unless more than half of its epoch's rows do; of the phase pairs
(:mod:`gnss_cli.pipeline.phase_rows`) every row above it -- and the segment
solved again, until the excluded set no longer changes (an excluded row comes back when the
new solution fits it). The variance factors stay those of the first pass (estimated again on
the kept rows, the gate would tighten itself pass after pass). Excluded pseudoranges are added
to the ``excluded`` column with the WLS exclusions; ``n_sat`` counts the pseudoranges used.
Measured with quadrature lag 3 and Doppler on the urban tst2 set (157 truth epochs; kf 2.14 m,
WLS 6.81 m): 9.06 m without the gate, 2.52 m with it; it costs 1-2 % on the simulated flights
(0.313 -> 0.317, 0.774 -> 0.78 x the truth-tuned KF+RTS) and on the Yamatogawa walk (2.67 -> 2.72
m). With ``robust = "huber"`` or ``"cauchy"`` every row is also reweighted by the M-estimator of
its standardized residual (:func:`~gnss_cli.solvers.robust.m_estimator_weights`), as in the
snapshot solution (tst2 with Huber: 1.90 m).

Gauss-Newton (with the robust weights: IRLS): linearize at the current trajectory (first the WLS
fixes, interpolated in time where an epoch has none), solve every segment, repeat until no
position moves more than 1 mm, no robust weight by more than 1e-3 and the excluded set is the
same (at most :data:`MAX_PASSES`).

A degenerate segment -- its system singular or nearly (reciprocal condition estimate below
:data:`MIN_RCOND`), e.g. two epochs of pseudoranges alone under ``quadrature`` or ``ca``, whose
velocities no row and no motion term fixes -- is not smoothed: its epochs keep their WLS fix
with the status ``fallback_wls`` (``rank_deficient`` for those without one), and its model
record has the status ``failed``.

Output: positions, velocities (zero for ``static``) and re-estimated clocks of every epoch of a
segment. Covariance: the position blocks of the estimator's covariance (the inverse KKT matrix,
with the weights as used: factors and robust weights;
:func:`~gnss_cli.behavior.kinematic_solve.kinematic_position_cov`), the clocks eliminated per
epoch as in :func:`~gnss_cli.behavior.multi_epoch.multi_epoch_cov`. The DOP columns are that
covariance over the median variance of the used pseudoranges (as for ``kf``): the multi-epoch
DOP, in which the other measurements and the motion add geometry. One
:class:`~gnss_cli.pipeline.results.WindowModel` per segment (the motion's noise-free kernel;
motion, misfit, degrees of freedom and variance factors in ``message``).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior import KernelRepresentation
from gnss_cli.behavior.kinematic_solve import (
    STEP_OFFSETS,
    Motion,
    MotionTerms,
    kinematic_position_cov,
    solve_kinematic,
    step_weights,
)
from gnss_cli.behavior.multi_epoch import epoch_information
from gnss_cli.behavior.records import kernel_record
from gnss_cli.behavior.window_solve import EpochNormals, reduce_epochs
from gnss_cli.behavior.windows import segments
from gnss_cli.config import ProcessingConfig
from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic
from gnss_cli.pipeline.kalman import nominal_trajectory
from gnss_cli.pipeline.kalman_rows import gate_threshold
from gnss_cli.pipeline.measurements import (
    KINDS,
    checked_measurements,
    default_measurements,
    epoch_normals,
    factors_from_totals,
    free_misfit_totals,
    gate_rows,
    kinds_text,
    measurement_rows,
    misfit_totals,
    pairs_alone,
    standardized,
)
from gnss_cli.pipeline.phase_rows import phase_pair_rows
from gnss_cli.pipeline.results import PASSED_FIX, EpochData, EpochStatus, MethodSolution, WindowModel, as_wls_used
from gnss_cli.pipeline.behavioral import finish_smoothing
from gnss_cli.solvers.dop import dop_from_cov

__all__ = ["smooth_segments", "solve_segments", "default_measurements", "motion_kernel", "SegmentRun", "KINDS",
           "MAX_PASSES", "MIN_RCOND", "misfit_totals", "factors_from_totals", "free_misfit_totals"]

F64 = NDArray[np.float64]

MAX_PASSES = 10
#: A segment whose system's reciprocal condition estimate is below this is degenerate (module docstring):
#: its solution would keep fewer than about four significant digits. Measured on a simulated flight, the
#: Yamatogawa walk and tst2 for every motion and measurement set: 1.4e-8 (tst2 with phase) to 3e-2;
#: two epochs of pseudoranges alone: exactly singular (quadrature) or 7e-36 (ca).
MIN_RCOND = 1e-12
_CONVERGED_M = 1e-3
_WEIGHT_TOL = 1e-3
#: The longest step inside a segment, in sampling intervals: up to four missed epochs are bridged by the
#: motion (the quadrature rule at the epochs' own times), a longer gap starts a new segment. ``kf``
#: bridges every gap up to ``[kalman] gap_s`` with its process noise; the quadrature rule's rows are
#: exact, so the smoother bridges only what a velocity polynomial spans.
MAX_STEP_INTERVALS = 5
GAP_FACTOR = MAX_STEP_INTERVALS + 0.5
"""The ``gap_factor`` of :func:`~gnss_cli.behavior.windows.segments` that keeps steps of up to
:data:`MAX_STEP_INTERVALS` sampling intervals in a segment."""


@dataclass(frozen=True, slots=True)
class SegmentRun:
    """The measurement-domain solution of every segment.

    Attributes
    ----------
    x_ecef_m, vel_ecef_m_s : ``(T, 3)``, NaN outside the solved segments.
    n_sat : ``(T,)`` pseudoranges of each epoch in the solve (robust weights aside).
    segments : epoch indices of each segment.
    misfit, dof : per segment, weighted residual square sum (NaN: degenerate) and its degrees of freedom.
    rcond : per segment, the reciprocal condition estimate of its system.
    factors : variance factors of the pseudoranges, the range rates and the phase pairs (1 for a kind not used).
    passes : Gauss-Newton (IRLS) passes.
    cov_m2 : ``(T, 3 + k, 3 + k)`` covariance of ``[x (ECEF), clocks]`` (m^2; NaN outside the solved segments).
    var0_m2 : median variance of the used pseudoranges (weights with their factor): the DOPs are
        ``cov_m2 / var0_m2``.
    gated : ``(T, n)`` pseudoranges the residual gate excluded.
    motion : the motion model.
    measurements : the kinds of measurements used.
    """

    x_ecef_m: F64
    vel_ecef_m_s: F64
    n_sat: NDArray[np.int64]
    segments: list[NDArray[np.intp]]
    misfit: list[float]
    dof: list[int]
    rcond: list[float]
    factors: tuple[float, ...]
    passes: int
    cov_m2: F64
    var0_m2: float
    gated: NDArray[np.bool_]
    motion: Motion
    measurements: frozenset[str]

    @property
    def degenerate(self) -> list[bool]:
        """Per segment: not solved (its system is singular or nearly)."""
        return [not r >= MIN_RCOND for r in self.rcond]


def motion_kernel(motion: Motion, dt_s: float) -> KernelRepresentation:
    """The noise-free behavior of ``motion`` as a kernel: on ``w = (x, v)`` (m, m/s) the quadrature
    rule of its lag (interior rule) or ``(x, v)(t+1) = F (x, v)(t)`` (``cv``); on ``(x, v, a)``
    ``(ca)``; ``(z - 1) I`` on ``x`` (``static``).

    >>> k = motion_kernel(Motion("quadrature", 3), 1.0)
    >>> t = np.arange(8.0)[:, None]
    >>> w = np.hstack([t**4 / 4 * [1, 2, 3], t**3 * [1, 2, 3]])  # cubic velocity
    >>> bool(k.annihilates(w, rtol=1e-12))
    True
    """
    if motion.name == "static":
        return KernelRepresentation(np.hstack([-np.eye(3), np.eye(3)]), q=3)
    if motion.name in ("cv", "ca"):
        k = motion.n_kin
        F = np.eye(k) + np.diag(np.full(k - 1, dt_s), 1) + (np.diag([dt_s**2 / 2], 2) if k == 3 else 0.0)
        return KernelRepresentation(np.hstack([-np.kron(F, np.eye(3)), np.eye(3 * k)]), q=3 * k)
    offs = STEP_OFFSETS[min(max(motion.lag, 1), 3)]
    wts = step_weights(offs)
    first = min(offs)
    blocks = [np.zeros((3, 6)) for _ in range(max(offs) - first + 1)]
    blocks[-first][:, :3] -= np.eye(3)
    blocks[1 - first][:, :3] += np.eye(3)
    for o, w in zip(offs, wts):
        blocks[o - first][:, 3:] -= w * dt_s * np.eye(3)
    return KernelRepresentation(np.hstack(blocks), q=6)


def _take(nrm: EpochNormals | None, seg: NDArray[np.intp]) -> EpochNormals | None:
    return None if nrm is None else EpochNormals(nrm.M[seg], nrm.r[seg], nrm.s[seg], nrm.n_rows[seg], nrm.n_free[seg])


def _segment_pairs(ph: EpochNormals, seg: NDArray[np.intp]) -> EpochNormals:
    """The pair normals of a segment's epochs: each epoch's pair differences it with the epoch before
    it in the data, so only where that is the segment's previous epoch (left out: the pair ending at
    its first epoch, from outside, and, in a tied ``stls`` run that bridges an epoch without a fix,
    the pair ending just after it)."""
    keep = np.r_[0.0, (np.diff(seg) == 1).astype(np.float64)]
    return EpochNormals(ph.M[seg] * keep[:, None, None], ph.r[seg] * keep[:, None], ph.s[seg] * keep,
                        ph.n_rows[seg] * keep.astype(np.int64), ph.n_free[seg] * keep.astype(np.int64))


def _solve_pass(segs: list[NDArray[np.intp]], normals: tuple[EpochNormals, EpochNormals | None, EpochNormals | None],
                nominal: F64, t: F64, motion: Motion, out: dict[str, list],  # type: ignore[type-arg]
                terms: list[MotionTerms] | None = None) -> tuple[F64, F64, float]:
    """Every segment solved at ``nominal``: positions and velocities (NaN off the solved segments), the
    largest move; ``out``: per segment misfit, dof and rcond (in place). ``terms``: each segment's
    model, when it is not ``motion``'s."""
    pr, rr, ph = normals
    x, v = np.full((t.size, 3), np.nan), np.full((t.size, 3), np.nan)
    moved = 0.0
    for i, seg in enumerate(segs):
        sub = _take(pr, seg)
        assert sub is not None
        sol = solve_kinematic(sub, _take(rr, seg), np.diff(nominal[seg], axis=0), np.diff(t[seg]), motion,
                              None if ph is None else _segment_pairs(ph, seg), None if terms is None else terms[i])
        out["rcond"][i] = sol.rcond
        out["dof"][i] = sol.dof
        if not sol.rcond >= MIN_RCOND:
            out["misfit"][i] = float("nan")
            continue
        x[seg], v[seg] = nominal[seg] + sol.z, sol.v
        out["misfit"][i] = sol.misfit
        moved = max(moved, float(np.abs(sol.z).max()))
    return x, v, moved


def solve_segments(data: EpochData, wls: MethodSolution, config: ProcessingConfig, motion: Motion,
                   measurements: frozenset[str], *, gap_factor: float = GAP_FACTOR,
                   factors: tuple[float, ...] | None = None,
                   plan: list[tuple[NDArray[np.intp], MotionTerms]] | None = None) -> SegmentRun | None:
    """Solve every segment (module docstring); None when WLS solved no epoch.

    ``data`` should carry the WLS exclusions in ``usable`` (:func:`smooth_segments` does);
    ``measurements`` are the kinds to use, checked against ``data`` by the caller.
    ``factors``: the variance factors, when they were estimated beforehand (a whole file's, for
    a piece of it); else they are estimated from ``data``. ``plan``: the segments (epoch indices)
    and each one's model, instead of ``motion`` on the segments of ``data`` (``stls``'s identified
    piecewise behavior, :mod:`gnss_cli.pipeline.tied`; ``motion`` then gives the state blocks,
    and the covariance is left to the caller: NaN).
    """
    t = data.time_gps_s
    fix = np.isin(wls.status, PASSED_FIX) & np.isfinite(wls.x_ecef_m).all(axis=1)
    if not fix.any():
        return None
    doppler, phase = "doppler" in measurements, "phase" in measurements
    if plan is None:
        segs = [s for s in segments(t, data.usable.any(axis=1), gap_factor) if s.size >= 2 and fix[s].any()]
        terms = None
    else:
        segs, terms = [p[0] for p in plan], [p[1] for p in plan]
    nominal = nominal_trajectory(t, np.where(fix[:, None], wls.x_ecef_m, np.nan))
    mult = np.ones((3, t.size, data.sv.size))  # robust weights times the gate (0: excluded): pr, rr, phase pairs
    gated = np.zeros((3, t.size, data.sv.size), dtype=bool)
    out: dict[str, list] = {"misfit": [0.0] * len(segs), "dof": [0] * len(segs), "rcond": [0.0] * len(segs)}  # type: ignore[type-arg]
    gate = np.inf if (limit := gate_threshold(config)) is None else limit
    passes = 0
    given = factors
    factors = (1.0, 1.0, 1.0) if given is None else (*given, 1.0, 1.0)[:3]
    for passes in range(1, MAX_PASSES + 1):
        rows = measurement_rows(data, nominal, config, doppler)
        phr = phase_pair_rows(data, rows, config) if phase else None
        if passes == 1 and given is None:  # before any exclusion: re-estimated on the kept rows, the gate would tighten itself
            factors = factors_from_totals(misfit_totals(*epoch_normals(rows, (mult[0], mult[1])), pairs_alone(phr, mult[2])))
        scale = (mult[0] / factors[0], mult[1] / factors[1])
        pr, rr = epoch_normals(rows, scale)
        ph = None if phr is None else reduce_epochs(phr["P6"], phr["w"] * mult[2] / factors[2], phr["y"], phr["C"])
        x, v, moved = _solve_pass(segs, (pr, rr, ph), nominal, t, motion, out, terms)
        have = np.isfinite(x).all(axis=1)
        z = np.where(have[:, None], x - nominal, 0.0)
        u = (standardized(rows["P"], rows["w"] / factors[0], rows["y"], rows["C"], z),
             np.zeros_like(rows["w"]) if rr is None else
             standardized(rows["H"], rows["wd"] / factors[1], rows["yd"], None, np.where(have[:, None], v, 0.0)),
             np.zeros_like(rows["w"]) if phr is None else
             standardized(phr["P6"], phr["w"] / factors[2], phr["y"], phr["C"], np.hstack([np.roll(z, 1, axis=0), z]),
                           mult[2]))
        unsolved = np.zeros(t.size, dtype=bool)  # epochs of degenerate segments: nothing to test there
        for i, seg in enumerate(segs):
            unsolved[seg] |= not out["rcond"][i] >= MIN_RCOND
        if unsolved.any():
            u = (np.where(unsolved[:, None], 0.0, u[0]), np.where(unsolved[:, None], 0.0, u[1]),
                 np.where(unsolved[:, None], 0.0, u[2]))
        nominal[have] = x[have]
        none = np.zeros_like(rows["w"], dtype=bool)
        used = (rows["w"] > 0, none if rr is None else rows["wd"] > 0, none if phr is None else phr["w"] > 0)
        new_mult, new_gated = gate_rows(u, used, gate, config)
        changed = float(np.abs(new_mult - mult).max())
        same_gate = bool(np.array_equal(new_gated, gated))
        mult, gated = new_mult, new_gated
        if moved < _CONVERGED_M and changed < _WEIGHT_TOL and same_gate:
            break
    assert factors is not None
    w_pr = rows["w"] * scale[0]
    solved = [s for s, r in zip(segs, out["rcond"]) if r >= MIN_RCOND]
    n_cov = 3 + rows["C"].shape[-1]
    cov = _covariance(rows["P"], w_pr, rows["C"], None if rr is None else rr.M, solved, t, motion,
                      None if ph is None else ph.M) if plan is None else np.full((t.size, n_cov, n_cov), np.nan)
    var0 = float(np.median(1.0 / w_pr[w_pr > 0])) if (w_pr > 0).any() else 1.0
    n_sat = ((rows["w"] > 0) & ~gated[0]).sum(axis=1).astype(np.int64)
    return SegmentRun(x, v, n_sat, segs, out["misfit"], out["dof"], out["rcond"], factors, passes, cov, var0, gated[0],
                      motion, measurements)


def smooth_segments(data: EpochData, wls: MethodSolution, config: ProcessingConfig, *, motion: str, lag: int,
                    measurements: Iterable[str], gap_factor: float = GAP_FACTOR, factors: tuple[float, ...] | None = None,
                    method: str = "smoother") -> tuple[MethodSolution, tuple[WindowModel, ...]]:
    """The ``smoother`` rows and one model record per segment (module docstring).

    Parameters
    ----------
    data : EpochData
        The prepared epochs (with carrier phase for ``"phase"``).
    wls : MethodSolution
        The WLS solution: satellites, weights and exclusions of the pseudoranges, first trajectory.
    config : ProcessingConfig
        Weights, corrections, ``doppler_sigma_m_s``, ``[kalman]`` PSDs (``cv``, ``ca``), phase
        sigma, ``integrity``, ``integrity_pfa``, ``robust``.
    motion : str
        ``quadrature``, ``cv``, ``ca`` or ``static``.
    lag : int
        Lag (>= 1) of the quadrature rule (1 trapezoid, 2 quadratic, >= 3 cubic); the other motions ignore it.
    measurements : set of str
        Kinds used, ``pseudorange`` and any of ``doppler``, ``phase`` (:func:`default_measurements`:
        every kind present).
    gap_factor : float
        A step longer than ``gap_factor`` times the median step splits a segment (default: steps of
        up to :data:`MAX_STEP_INTERVALS` intervals are bridged).
    factors : tuple of float, optional
        Variance factors estimated beforehand (:func:`free_misfit_totals` of a whole file).
    method : str
        Method key of the result.

    Returns
    -------
    solution, models

    Raises
    ------
    ConfigError
        Unknown motion or measurement kind, a lag below 1 with ``quadrature``, or a kind the file does not have.
    """
    mot = Motion(motion, lag, config.kalman.accel_psd_m2_s3, config.kalman.jerk_psd_m2_s5).validated()
    kinds = checked_measurements(data, measurements)
    data = as_wls_used(data, wls)  # its satellites and weights
    run = solve_segments(data, wls, config, mot, kinds, gap_factor=gap_factor, factors=factors)
    if run is None:
        return replace(wls, method=method), ()
    smoothed = np.isfinite(run.x_ecef_m).all(axis=1)
    # an epoch left out of every segment (alone between two gaps) keeps its WLS fix, and says so
    status = np.where(smoothed, EpochStatus.OK.value,
                      np.where(wls.status == EpochStatus.OK.value, EpochStatus.FALLBACK_WLS.value, wls.status.astype("<U24")))
    for seg, bad in zip(run.segments, run.degenerate):
        if bad:
            status[seg] = np.where(wls.status[seg] == EpochStatus.OK.value, EpochStatus.FALLBACK_WLS.value,
                                   EpochStatus.RANK_DEFICIENT.value)
    x_s = np.where(smoothed[:, None], run.x_ecef_m, wls.x_ecef_m)
    kept = replace(data, usable=data.usable & ~run.gated)  # clocks and residuals from the rows used
    sol = _with_covariance(finish_smoothing(kept, wls, config, x_s, status, smoothed, [], method), run, smoothed)
    sol = replace(sol, excluded=run.gated if wls.excluded is None else (wls.excluded | run.gated))
    vel = np.where(smoothed[:, None], run.vel_ecef_m_s, sol.vel_ecef_m_s if sol.vel_ecef_m_s is not None else np.nan)
    return replace(sol, vel_ecef_m_s=vel), tuple(_models(data, run, method))


def _models(data: EpochData, run: SegmentRun, method: str = "smoother") -> list[WindowModel]:
    """One record per segment: the motion's kernel, misfit and what was used (``failed`` when degenerate)."""
    mot = run.motion
    what = f"motion {mot.name}" + (f" (lag {min(mot.lag, 3)})" if mot.name == "quadrature" else "")
    used = kinds_text(run.measurements)
    models = []
    for k, seg in enumerate(run.segments):
        steps = np.diff(data.time_gps_s[seg])
        dt = float(np.median(steps))
        gaps = int(np.count_nonzero(steps > 1.5 * dt))
        bridged = f", bridging {gaps} step{'s' if gaps > 1 else ''} of missed epochs" if gaps else ""
        common = dict(segment=k, window=0, start_time_gps_s=float(data.time_gps_s[seg[0]]),
                      end_time_gps_s=float(data.time_gps_s[seg[-1]]), n_epochs=int(seg.size), model=f"motion {mot.name}",
                      structure="full", method=method)
        if run.degenerate[k]:
            models.append(WindowModel(**common, kernel=None, misfit=None, status="failed",  # type: ignore[arg-type]
                                      message=(f"{what}, {used}: degenerate segment, reciprocal condition "
                                               f"{run.rcond[k]:.1e} < {MIN_RCOND:.0e}; epochs keep their WLS fix")))
            continue
        models.append(WindowModel(
            **common, kernel=kernel_record(motion_kernel(mot, dt)), misfit=run.misfit[k], status="converged",  # type: ignore[arg-type]
            message=(f"{what}, {used}; measurement domain{bridged}, {run.dof[k]} degrees of freedom, misfit per degree of "
                     f"freedom {run.misfit[k] / max(run.dof[k], 1):.3g}; variance factors: "
                     f"pseudoranges {run.factors[0]:.4g}"
                     + (f", range rates {run.factors[1]:.4g}" if "doppler" in run.measurements else "")
                     + (f", phase pairs {run.factors[2]:.4g}" if "phase" in run.measurements else "")
                     + f" ({run.passes} passes)"),
        ))
    return models


def _covariance(p_m: F64, w_pr: F64, clock_cols: F64, M_rr: F64 | None, segs: list[NDArray[np.intp]], t: F64,
                motion: Motion, M_ph: F64 | None = None) -> F64:
    """``(T, 3 + k, 3 + k)`` covariance of positions and clocks: the multi-epoch position blocks
    (:func:`~gnss_cli.behavior.kinematic_solve.kinematic_position_cov`), the clocks by eliminating
    them per epoch (as :func:`~gnss_cli.behavior.multi_epoch.multi_epoch_cov`)."""
    T, k = w_pr.shape[0], clock_cols.shape[-1]
    info, h, clock_var = epoch_information(p_m, w_pr, clock_cols)
    out = np.full((T, 3 + k, 3 + k), np.nan)
    for seg in segs:
        c = kinematic_position_cov(info[seg], None if M_rr is None else M_rr[seg], np.diff(t[seg]), motion,
                                   M_ph=None if M_ph is None else M_ph[seg])
        ch = np.einsum("tij,tcj->tic", c, h[seg])
        blk = np.empty((seg.size, 3 + k, 3 + k))
        blk[:, :3, :3] = c
        blk[:, :3, 3:] = -ch
        blk[:, 3:, :3] = -ch.transpose(0, 2, 1)
        blk[:, 3:, 3:] = np.einsum("tci,tid->tcd", h[seg], ch)
        blk[:, 3 + np.arange(k), 3 + np.arange(k)] += np.where(clock_var[seg] > 0, clock_var[seg], np.nan)
        out[seg] = blk
    return out


def _with_covariance(sol: MethodSolution, run: SegmentRun, smoothed: NDArray[np.bool_]) -> MethodSolution:
    """The multi-epoch covariance and DOPs (``cov / var0``) on the smoothed rows; a clock without
    pseudoranges at an epoch has no TDOP."""
    rows = np.flatnonzero(smoothed & np.isfinite(run.cov_m2[:, :3, :3]).all(axis=(1, 2)))
    if not rows.size:
        return sol
    cov = sol.cov_m2.copy()
    cov[rows] = np.nan_to_num(run.cov_m2[rows], nan=0.0)
    lat, lon, _ = ecef2geodetic(sol.x_ecef_m[rows])
    q = cov[rows] / run.var0_m2
    d = dop_from_cov(q, ecef2enu_rotation(lat, lon))
    k = q.shape[-1] - 3
    clk = run.cov_m2[rows][:, 3 + np.arange(k), 3 + np.arange(k)]
    dops = {}
    for name in ("gdop", "pdop", "hdop", "vdop", "tdop"):
        col = getattr(sol, name).copy()
        col[rows] = getattr(d, name)
        dops[name] = col
    dops["tdop"][rows] = np.where(np.isfinite(clk[:, 0]), dops["tdop"][rows], np.nan)
    tdops = None
    if sol.tdops is not None:
        tdops = sol.tdops.copy()
        tdops[rows] = np.where(np.isfinite(clk), np.sqrt(np.clip(np.nan_to_num(clk), 0.0, None) / run.var0_m2), np.nan)
    return replace(sol, cov_m2=cov, tdops=tdops, **dops)
