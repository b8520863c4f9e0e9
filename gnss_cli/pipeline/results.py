"""What a run produces: prepared epochs, per-method solutions, window models, epoch statuses.

Epoch status
------------
Every epoch of every method carries one word of :class:`EpochStatus` (the CSV ``status``
column). The solvers report a :class:`~gnss_cli.solvers.Status` per epoch and the behavioral
identification a :class:`~gnss_cli.behavior.StlsStatus` per window; :func:`solver_epoch_status`
and :func:`window_epoch_status` are the one place where they become epoch statuses:

======================  ==========================================================================
value                   meaning
======================  ==========================================================================
``ok``                  solved: Gauss-Newton converged (ls, wls), the one linear step succeeded
                        (tls, dls, mtls, stls, wtls), or the epoch was solved by a multi-epoch
                        method (stls with lag, smoother, kf); and, with ``integrity`` not
                        ``off``, the fix passed its integrity test (with at least one degree of
                        freedom), its GDOP limit and the alert limits (with ``off``: solved,
                        not tested)
``iteration_limit``     ls/wls: no convergence within ``max_iterations`` (position left empty)
``too_few_satellites``  fewer usable satellites than ``min_satellites`` or than 3 + clocks
``rank_deficient``      solver: the (weighted) design matrix is rank deficient
``nongeneric``          solver: nongeneric TLS problem (no unique solution)
``non_finite``          solver: non-finite values in the computation
``too_few_rows``        solver: fewer used rows than unknowns
``degenerate_data``     solver: degenerate data (e.g. a zero augmented matrix)
``fallback_wls``        stls with lag: the segment was too short, the window fit failed, or the
                        behavior test rejected even the shortest window (smoother: a degenerate
                        segment); the WLS fix, covariance and DOPs are kept
``integrity_fail``      the chi-square test of the residuals fails: ls/wls when no satellite can
                        be excluded any more (``integrity = "check"``: when it fails); every other
                        method (tls ... wtls, stls with lag, smoother, kf) when it fails at the
                        method's own fix; position kept
``gdop_limit``          GDOP above ``max_gdop`` (position kept; for tls ... wtls their own GDOP,
                        with ``integrity`` check or fde)
``hpl_limit``           the test passes but the horizontal protection level (of the WLS epoch
                        for tls ... wtls; a multi-epoch row's own) exceeds ``alert_limit_h_m``
                        (position kept)
``vpl_limit``           the test passes and the HPL is within its limit, but the vertical
                        protection level exceeds ``alert_limit_v_m`` (position kept)
``untested``            the fix has no redundancy to test (``dof = n - (3 + k) = 0``; a
                        multi-epoch row ``n - k = 0``, or no protection level because its WLS
                        epoch has none), or its protection levels are infinite (the faults no
                        hypothesis covers exceed ``integrity_risk``): no test or no level;
                        position kept, not counted as solved
``nlos_dependent``      ls/wls and the snapshot methods solved at its fix, with the NLOS detector
                        and ``[nlos] min_direct_dof`` > 0: the fix passes its test and its alert
                        limits, but the satellites the detector leaves at full weight give it
                        fewer than ``min_direct_dof`` redundant measurements -- it rests on
                        suspected reflections; position and levels kept, not counted as solved
``predicted``           kf: no usable measurement at this epoch; the position is the motion
                        model's (filtered, or smoothed from both sides)
======================  ==========================================================================

A kf epoch is ``ok`` when the filter updated it with at least one pseudorange (1-3 satellites
included). Only ``ok``, ``fallback_wls``, ``integrity_fail``, ``gdop_limit``, ``hpl_limit``,
``vpl_limit``, ``untested``, ``nlos_dependent`` and ``predicted`` epochs have a position
(:data:`KEEPS_POSITION`); only ``ok`` ones count as solved. A window model record
(:class:`WindowModel`) has its own status: the identification outcome
(:class:`~gnss_cli.behavior.StlsStatus` name, e.g. ``converged``, ``direct``) or ``failed``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any
from dataclasses import dataclass, field, fields, replace
from enum import Enum

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior import StlsStatus
from gnss_cli.behavior.records import KernelRecord
from gnss_cli.solvers import Status

F64 = NDArray[np.float64]
Progress = Callable[[str, float], None]
"""Progress callback: ``(stage, fraction done in [0, 1])``."""


class EpochStatus(str, Enum):
    """Status of one epoch of one method (module docstring: the table of values)."""

    OK = "ok"
    ITERATION_LIMIT = "iteration_limit"
    TOO_FEW_SATELLITES = "too_few_satellites"
    RANK_DEFICIENT = "rank_deficient"
    NONGENERIC = "nongeneric"
    NON_FINITE = "non_finite"
    TOO_FEW_ROWS = "too_few_rows"
    DEGENERATE_DATA = "degenerate_data"
    FALLBACK_WLS = "fallback_wls"
    INTEGRITY_FAIL = "integrity_fail"
    GDOP_LIMIT = "gdop_limit"
    HPL_LIMIT = "hpl_limit"
    VPL_LIMIT = "vpl_limit"
    UNTESTED = "untested"
    NLOS_DEPENDENT = "nlos_dependent"
    PREDICTED = "predicted"

    def __str__(self) -> str:
        return self.value


KEEPS_POSITION = (EpochStatus.OK.value, EpochStatus.FALLBACK_WLS.value,
                  EpochStatus.INTEGRITY_FAIL.value, EpochStatus.GDOP_LIMIT.value, EpochStatus.HPL_LIMIT.value,
                  EpochStatus.VPL_LIMIT.value, EpochStatus.UNTESTED.value, EpochStatus.NLOS_DEPENDENT.value,
                  EpochStatus.PREDICTED.value)
"""Statuses of epochs whose position, clocks and DOPs are written."""

PASSED_FIX = (EpochStatus.OK.value, EpochStatus.NLOS_DEPENDENT.value)
"""WLS statuses of fixes that passed their test: the multi-epoch methods start from these fixes
(``nlos_dependent`` says how far the epoch alone can be trusted, not that its fix failed)."""

_SOLVER_STATUS = {
    Status.CONVERGED: EpochStatus.OK,
    Status.ITERATION_LIMIT: EpochStatus.ITERATION_LIMIT,
    Status.RANK_DEFICIENT: EpochStatus.RANK_DEFICIENT,
    Status.NONGENERIC: EpochStatus.NONGENERIC,
    Status.NON_FINITE: EpochStatus.NON_FINITE,
    Status.TOO_FEW_ROWS: EpochStatus.TOO_FEW_ROWS,
    Status.DEGENERATE_DATA: EpochStatus.DEGENERATE_DATA,
}

WINDOW_FAILED = "failed"
"""Status of a window model record whose fit failed (no kernel, no misfit)."""
WINDOW_REJECTED = "rejected"
"""Status of an ``stls`` window whose behavior test failed (kernel and misfit kept; its epochs went to
shorter windows or keep the WLS fix, :mod:`gnss_cli.pipeline.spans`)."""


def solver_epoch_status(code: int | Status) -> EpochStatus:
    """The epoch status of a solver outcome (:class:`~gnss_cli.solvers.Status` code)."""
    return _SOLVER_STATUS[Status(int(code))]


def window_epoch_status(status: StlsStatus | None) -> EpochStatus:
    """The status of the epochs a smoothing window supplies: ``ok`` when its fit has a
    trajectory (``status >= 0``), ``fallback_wls`` when it failed (``None`` or negative)."""
    return EpochStatus.OK if status is not None and status >= 0 else EpochStatus.FALLBACK_WLS


def window_status_word(status: StlsStatus | None) -> str:
    """The status word of a window model record: the identification outcome or ``failed``."""
    return WINDOW_FAILED if status is None or status < 0 else StlsStatus(int(status)).name.lower()


@dataclass(frozen=True, slots=True)
class WindowModel:
    """The behavioral model of one smoothing window (one record of ``--model-out``).

    Attributes
    ----------
    segment, window : int
        Segment index and window index within it.
    start_time_gps_s, end_time_gps_s : float
        First and last epoch of the window, s since the GPS epoch.
    n_epochs : int
        Epochs in the window.
    model : str
        ``identified`` (``stls``: a kernel identified in the window) or the ``smoother``'s fixed
        motion model (``motion quadrature``, ...).
    structure : str
        ``shared`` or ``full`` (the fixed models are shared).
    kernel : KernelRecord or None
        The kernel, None when the fit failed.
    misfit : float or None
        Weighted misfit (dimensionless), None when the fit failed.
    status : str
        :func:`window_status_word`.
    message : str
        Explanation of the status.
    """

    segment: int
    window: int
    start_time_gps_s: float
    end_time_gps_s: float
    n_epochs: int
    model: str
    structure: str
    kernel: KernelRecord | None
    misfit: float | None
    status: str
    message: str
    method: str = "stls"
    """The method whose rows the window supplies (``stls``, ``smoother``)."""
    iterations: int | None = None
    """Alternations of the measurement-domain ``stls`` window (None: not alternated)."""
    converged: bool | None = None
    """Whether that alternation converged (False: the position-domain result was kept)."""
    test_stat: float | None = None
    """The behavior test's statistic (:func:`gnss_cli.pipeline.identified.behavior_tests`; None: not tested)."""
    test_dof: int | None = None
    """Its degrees of freedom."""
    test_limit: float | None = None
    """Its limit at ``[stls] behavior_pfa`` (above it the window is ``rejected``, :mod:`gnss_cli.pipeline.spans`)."""
    n_supplied: int | None = None
    """Epochs the window answers for (``stls``: overlapping windows each supply the epochs nearest
    their centre, so two records of one window can supply different epochs; a rejected window: 0
    when its epochs were solved again, else those that kept their WLS fix, as its message says;
    None: every epoch of the window, as a ``smoother`` segment)."""
    supplied_start_time_gps_s: float | None = None
    """First epoch the window supplies, s since the GPS epoch (None when it supplies none or all)."""
    supplied_end_time_gps_s: float | None = None
    """Last epoch it supplies."""

    def to_dict(self) -> dict[str, object]:
        """A JSON-serialisable record (the ``windows`` entries of ``--model-out``)."""
        out: dict[str, object] = {
            "method": self.method, "segment": self.segment, "window": self.window, "start_time_gps_s": self.start_time_gps_s,
            "end_time_gps_s": self.end_time_gps_s, "n_epochs": self.n_epochs, "model": self.model,
            "structure": self.structure,
        }
        if self.kernel is None:
            out.update({"status": self.status, "message": self.message, "misfit": self.misfit})
        else:
            out.update(self.kernel.to_dict())
            out.update({"misfit": self.misfit, "status": self.status, "message": self.message})
        if self.n_supplied is not None:
            out["n_supplied"] = self.n_supplied
            if self.supplied_start_time_gps_s is not None:
                out.update({"supplied_start_time_gps_s": self.supplied_start_time_gps_s,
                            "supplied_end_time_gps_s": self.supplied_end_time_gps_s})
        if self.iterations is not None:
            out.update({"iterations": self.iterations, "converged": self.converged})
        if self.test_stat is not None:
            out.update({"behavior_test_stat": self.test_stat, "behavior_test_dof": self.test_dof,
                        "behavior_test_limit": self.test_limit})
        return out


UNUSED_REASONS = ("", "no_ephemeris", "excluded_by_user", "snr_mask", "ephemeris_sigma")
"""Reasons (``satellites.csv`` ``reason``) an observed satellite is not usable before solving
(``ephemeris_sigma``: the broadcast orbit-and-clock sigma exceeds
:data:`~gnss_cli.gnss.broadcast.MAX_EPHEMERIS_SIGMA_M`)."""
DOWNWEIGHTED_BELOW = 0.1
"""A used satellite whose robust weight factor is below this is reported (``satellites.csv``
``reason`` ``downweighted``): Huber ``|u| > 13.45``, Cauchy ``|u| > 7.2`` a-priori sigmas."""
EPOCH_AXIS_FIELDS = ("time_gps_s", "pr_corrected_m", "sat_ecef_m", "ura_m", "usable", "iono_scale", "snr_dbhz", "unused",
                     "range_rate_m_s", "sat_vel_ecef_m_s", "sat_clock_drift_s_s", "phase_m", "phase_slip",
                     "variance_scale")
"""Fields of :class:`EpochData` with the epoch axis first."""


@dataclass(frozen=True)
class EpochData:
    """Everything the estimators need, prepared once per run.

    Attributes
    ----------
    time_gps_s : ``(T,)`` epochs, s since the GPS epoch.
    sv : ``(n,)`` satellite ids.
    pr_corrected_m : ``(T, n)`` pseudorange + c (satellite clock - TGD), m (NaN = unusable).
    sat_ecef_m : ``(T, n, 3)`` satellite positions at transmit time, m.
    ura_m : ``(T, n)`` broadcast orbit-and-clock error sigma, m
        (:func:`~gnss_cli.gnss.broadcast.ephemeris_sigma_m`).
    usable : ``(T, n)`` observation with a usable ephemeris.
    klobuchar : ``(alpha, beta)`` or None.
    approx_ecef_m : ``(3,)`` header approximate position or None.
    marker_name : from the observation header.
    """

    time_gps_s: F64
    sv: NDArray[np.str_]
    pr_corrected_m: F64
    sat_ecef_m: F64
    ura_m: F64
    usable: NDArray[np.bool_]
    klobuchar: tuple[F64, F64] | None
    approx_ecef_m: F64 | None
    marker_name: str = ""
    obs_path: str = ""
    nav_paths: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    systems: tuple[str, ...] = ("G",)
    """Receiver clocks of the systems with usable data, in clock-column order (column 3 + j is clock
    j); QZSS satellites share GPS's column unless ``qzss_own_clock`` (:func:`~gnss_cli.pipeline.epochs.clock_systems`)."""
    system_index: NDArray[np.int64] | None = None
    """``(n,)`` index into ``systems`` of every satellite's clock."""
    iono_scale: F64 | None = None
    """``(T, n)`` factor taking the L1 Klobuchar delay to the signal's frequency."""
    leap_seconds: float | None = None
    """GPS - UTC (s) from the navigation header's ``LEAP SECONDS``, None when absent."""
    snr_dbhz: F64 | None = None
    """``(T, n)`` carrier-to-noise density of the chosen code's signal, dB-Hz (NaN: none)."""
    unused: NDArray[np.int8] | None = None
    """``(T, n)`` why an observed satellite is not usable (:data:`UNUSED_REASONS` index;
    0 usable, -1 not observed)."""
    variance_scale: F64 | None = None
    """``(T, n)`` factor on each pseudorange's variance (>= 1): the NLOS detector's reflections that
    an epoch's redundancy keeps (``[nlos] variance_factor``, :func:`as_wls_used`); None: 1."""
    range_rate_m_s: F64 | None = None
    """``(T, n)`` range rate from the Doppler of the chosen code's signal, ``-lambda D`` (m/s;
    lambda of that signal, GLONASS per channel); NaN where there is no Doppler or the
    pseudorange is not usable. None when the observation file has no Doppler."""
    sat_vel_ecef_m_s: F64 | None = None
    """``(T, n, 3)`` satellite velocity at transmit time, ECEF (rotating frame), m/s (with Doppler)."""
    sat_clock_drift_s_s: F64 | None = None
    """``(T, n)`` satellite clock drift at transmit time, s/s (broadcast clock with its
    relativistic term; with Doppler)."""
    phase_m: F64 | None = None
    """``(T, n)`` carrier phase of the chosen code's signal times its wavelength (iono-free: the
    ionosphere-free combination of both signals' phases, as ``pr_corrected_m``), plus c times the
    satellite clock (as ``pr_corrected_m``), m; its ambiguity is unknown, only time differences
    are used. NaN where there is no phase or the pseudorange is not usable. None when the file has
    no phase of any chosen code (or ``phase`` is not among the measurements)."""
    phase_slip: NDArray[np.bool_] | None = None
    """``(T, n)`` the phase may have slipped since the previous epoch: loss-of-lock indicator bit 0,
    or a jump against the Doppler (:func:`~gnss_cli.gnss.carrier.phase_slips`)."""

    @property
    def clock_index(self) -> NDArray[np.int64]:
        """``(n,)`` clock column (index into ``systems``) of every satellite: ``system_index``, or
        0 for every satellite (one clock) when it is None."""
        return self.system_index if self.system_index is not None else np.zeros(self.sv.size, dtype=np.int64)


@dataclass(frozen=True)
class MethodSolution:
    """Per-epoch results of one method.

    Attributes
    ----------
    method : registry key.
    x_ecef_m : ``(T, 3)`` receiver positions (NaN where the epoch failed).
    clocks_m : ``(T, k)`` receiver clock of every system (column j: ``EpochData.systems[j]``),
        m; :attr:`clock_m` is the reference clock, column 0 (the CSV ``clock_m``).
    n_sat : ``(T,)`` satellites used.
    gdop, pdop, hdop, vdop, tdop : ``(T,)`` DOPs from the method's noise gain ``J J^T``
        at the solution, position rotated to local ENU (unitless). ``tdop`` is the TDOP of
        the reference clock, the first of ``EpochData.systems`` (= ``tdops[:, 0]``); ``gdop``
        includes every clock.
    gdop_paper : ``(T,)`` the paper's GDOP formula for the method: TLS ``(A^T A - s^2 I)^-1 A^T A (...)^-1``;
        ``stls`` with lag >= 1 its STLS GDOP on ``H_{l+1}(w)`` (1/m, :mod:`gnss_cli.behavior.paper_gdop`); else None.
    cov_m2 : ``(T, 3 + k, 3 + k)`` the estimator covariance ``J Sigma J^T`` for the
        configured pseudorange variances (ECEF position, one clock per system), m^2.
    status : ``(T,)`` status words, values of :class:`EpochStatus`.
    iterations : ``(T,)`` Gauss-Newton iterations.
    residuals_m : ``(T, n)`` post-fit residuals of the used rows (NaN elsewhere); for tls, dls,
        mtls, stls and wtls with ``integrity`` check or fde, the observed minus modelled
        pseudoranges at the method's fix (those of its test statistic).
    """

    method: str
    x_ecef_m: F64
    clocks_m: F64
    n_sat: NDArray[np.int64]
    gdop: F64
    pdop: F64
    hdop: F64
    vdop: F64
    tdop: F64
    gdop_paper: F64 | None
    cov_m2: F64
    status: NDArray[np.str_]
    iterations: NDArray[np.int64]
    residuals_m: F64
    tdops: F64 | None = None
    """``(T, k)`` TDOP of every system's clock, ``sqrt((J J^T)_{3+j,3+j})``; NaN where the
    epoch failed or used no satellite of that system (its clock is then fixed by a constraint)."""
    excluded: NDArray[np.bool_] | None = None
    """``(T, n)`` satellites excluded by the integrity monitoring (fault detection and
    exclusion) of the WLS fix; the other methods use the WLS set, so they carry the same."""
    sigma_m: F64 | None = None
    """``(T, n)`` pseudorange sigma of the used rows (the weights' model), m (NaN elsewhere)."""
    test_stat: F64 | None = None
    """``(T,)`` chi-square statistic ``sum r_i^2 / sigma_i^2`` of the final residuals (ls/wls), or of
    the pseudorange residuals at the method's fix with the WLS sigmas (the other snapshot methods);
    not computed (NaN, or None) with ``integrity = "off"``."""
    hpl_m: F64 | None = None
    """``(T,)`` horizontal protection level, m (solution separation over single-satellite and
    constellation faults, :mod:`gnss_cli.pipeline.integrity`): ls/wls; for the multi-epoch
    methods the levels of their own positions from the WLS epoch's subsets
    (:func:`~gnss_cli.pipeline.integrity.estimate_levels`); NaN for tls ... wtls and untested rows."""
    vpl_m: F64 | None = None
    """``(T,)`` vertical protection level, m."""
    robust_weights: F64 | None = None
    """``(T, n)`` robust weight factor ``w(u_i) = psi(u_i) / u_i`` in (0, 1] of the used rows
    (``config.robust``, ls/wls; 1 for a plain fit): the effective weight is ``w_i / sigma_i^2``
    (NaN for rows not used)."""
    vel_ecef_m_s: F64 | None = None
    """``(T, 3)`` receiver velocity, ECEF, m/s: Doppler WLS at the fix, or the kf state (None without Doppler)."""
    clock_drift_m_s: F64 | None = None
    """``(T,)`` receiver clock drift times c, m/s (one for every system)."""
    gdop_vel: F64 | None = None
    """``(T,)`` velocity DOP ``sqrt(trace)`` of the velocity-and-drift noise gain (unitless)."""
    variance_scale: F64 | None = None
    """``(T, n)`` the factor on each pseudorange variance the solution was weighted with (the NLOS
    detector's kept reflections, ``[nlos] variance_factor``); None: 1 everywhere. Every method
    that starts from this WLS solution weights its epochs alike (:func:`as_wls_used`)."""

    @property
    def clock_m(self) -> F64:
        """``(T,)`` the reference clock (the first system's), m: the CSV ``clock_m`` column."""
        return self.clocks_m[:, 0]


@dataclass(frozen=True)
class RunResult:
    """A whole run: the prepared epochs, one solution per method, the window models and what ran.

    ``models`` holds one :class:`WindowModel` per window of the multi-epoch methods that fit
    models (``stls`` with ``lag >= 1``: each window's identified kernel; ``smoother``: one per
    segment), else it is empty. ``settings`` holds each method's resolved settings
    (:class:`~gnss_cli.pipeline.methods.MethodSettings`).
    """

    epochs: EpochData
    solutions: dict[str, MethodSolution] = field(default_factory=dict)
    models: tuple[WindowModel, ...] = ()
    settings: dict[str, Any] = field(default_factory=dict)
    environment: str = ""
    """The environment the run took and why (:func:`~gnss_cli.pipeline.environment.describe`;
    empty for a part: set on the whole run by :func:`~gnss_cli.pipeline.run.process`)."""

    @property
    def warnings(self) -> tuple[str, ...]:
        return self.epochs.warnings


def as_wls_used(data: EpochData, wls: MethodSolution) -> EpochData:
    """``data`` as the WLS solution ``wls`` used it, for the methods that start from it: without
    the satellites it excluded (FDE, the NLOS detector) and weighted as it was (its
    ``variance_scale``, the NLOS detector's down-weighted reflections). Applying it twice changes
    nothing."""
    if wls.excluded is not None:
        data = replace(data, usable=data.usable & ~wls.excluded)
    if wls.variance_scale is not None:
        data = replace(data, variance_scale=np.nan_to_num(wls.variance_scale, nan=1.0))
    return data


def take_solution(sol: MethodSolution, rows: NDArray[np.intp] | slice, copy: bool = False) -> MethodSolution:
    """The epochs ``rows`` of ``sol`` (every per-epoch array; copies with ``copy``)."""
    return replace(sol, **{f.name: (getattr(sol, f.name)[rows].copy() if copy else getattr(sol, f.name)[rows])
                           for f in fields(MethodSolution) if isinstance(getattr(sol, f.name), np.ndarray)})


def take_result(result: RunResult, rows: slice, copy: bool = False) -> RunResult:
    """The epochs ``rows`` of ``result`` (no window models): views, or copies with ``copy``
    (that do not keep the whole of ``result``'s arrays alive)."""
    epochs = replace(result.epochs, **{f: (getattr(result.epochs, f)[rows].copy() if copy else getattr(result.epochs, f)[rows])
                                       for f in EPOCH_AXIS_FIELDS if getattr(result.epochs, f) is not None})
    return RunResult(epochs, {m: take_solution(s, rows, copy) for m, s in result.solutions.items()},
                     settings=result.settings)


def concat_results(parts: list[RunResult]) -> RunResult:
    """The epochs of ``parts`` one after the other (one satellite axis, the same methods), their models joined."""
    first = parts[0]
    if len(parts) == 1:
        return first
    epochs = replace(first.epochs, **{f: np.concatenate([getattr(p.epochs, f) for p in parts])
                                      for f in EPOCH_AXIS_FIELDS if getattr(first.epochs, f) is not None})
    sols = {m: replace(s, **{f.name: np.concatenate([getattr(p.solutions[m], f.name) for p in parts])
                             for f in fields(MethodSolution) if isinstance(getattr(s, f.name), np.ndarray)})
            for m, s in first.solutions.items()}
    return RunResult(epochs, sols, tuple(w for p in parts for w in p.models), first.settings)
