"""The ``stls`` method with ``lag >= 1``: the paper's identified Hankel STLS over sliding windows.

The per-epoch WLS fixes ``x_t`` and their position covariances ``Sigma_t`` are rotated to a
local ENU frame (origin: the first solved fix of each segment), split into segments of
uniformly sampled epochs with a WLS fix (every status that keeps a position, ``integrity_fail``
included: ``smoother`` and ``kf`` take those epochs too, through their gates, and a segment cut at
each of them held tst2's 986 epochs in 79 pieces of at most 65), cut into sliding windows (:mod:`gnss_cli.behavior.windows`)
and, in each window, a kernel ``R(z)`` of lag ``L`` is identified by weighted Hankel STLS and the
fixes are projected onto its behavior (DESIGN.md section 5), as configured in ``[stls]``
(:class:`~gnss_cli.config.StlsConfig`): ``stls(..., structure=kernel)``; the shared kernel keeps a
fixed root at ``z = 1`` so the result does not depend on the ENU origin.

Each window is fitted with a single descent from the better of the WTLS and polynomial
starts (``stls(..., max_starts=1, restarts=False)``). The extra starts and restarts of the
default ``stls`` changed the 3D RMS of the simulated flights (1 m noise) by little: 1.39
instead of 1.42 m over 10 minutes, 1.34 m either way over an hour. Windows of up to
:data:`BATCH_MAX_EPOCHS` epochs with a shared kernel are fitted all at once
(:mod:`gnss_cli.behavior.batch`, the same algorithm with a leading window axis): a day of
1 s epochs is twelve thousand 15-epoch windows, and one at a time their cost would be the
Python overhead of many tiny array operations. Full kernels and longer windows go one at a
time through the banded O(T) STLS.

That position-domain result is the start of the method ``stls --lag L`` runs: with
``measurements`` (:func:`smooth`; :func:`gnss_cli.pipeline.methods.solve_multi_epoch` passes the
kinds of ``--measurements``), every shared-kernel window is then solved in the measurement domain
by alternating between the kernel and the trajectory (:mod:`gnss_cli.pipeline.identified`); a
window where that fails keeps the result above and its record says so. Full kernels stay in the
position domain.

Where the windows are not tied into one trajectory (the position domain, and the pseudoranges
alone) they overlap, and each epoch's position is their cross-fade: the mean of every accepted
window's estimate of it, weighted by a triangle over each window (:func:`window_weights`,
:func:`blended`; the covariance, the same mean of the windows' covariances, bounds the
covariance of that mean). On the simulated training flights and drives with the pseudoranges
alone, whole segments split by the behavior test, the 3D RMS went from 1.237 m with the
estimate of the window nearest each epoch to 1.158 m.

The receiver clocks (one per system, as in the snapshot solution) are re-estimated per
epoch at the smoothed position (one weighted clock-only least-squares solve on
:func:`gnss_cli.gnss.range_model.linearize`; a system without satellites keeps its
clock-fixing constraint row). Covariances and DOPs are the multi-epoch ones of
:mod:`gnss_cli.behavior.multi_epoch`; for an identified kernel the basis is the free
response of the identified behavior (first order: the kernel is held fixed).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior import STATUS_MESSAGES, SingularGramError, StlsStatus, stls
from gnss_cli.behavior.batch import identify_windows
from gnss_cli.behavior.multi_epoch import behavior_basis, epoch_information, shared_behavior_bases, window_covs
from gnss_cli.behavior.records import KernelRecord, kernel_record, shared_kernel_records
from gnss_cli.behavior.windows import segments, windows
from gnss_cli.config import ProcessingConfig, StlsConfig
from gnss_cli.errors import GnssError, UsageError
from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic
from gnss_cli.gnss.range_model import linearize
from gnss_cli.pipeline.multi_epoch_dop import with_paper_gdop
from gnss_cli.pipeline.results import (
    KEEPS_POSITION,
    EpochData,
    EpochStatus,
    MethodSolution,
    WINDOW_REJECTED,
    WindowModel,
    window_epoch_status,
    window_status_word,
    as_wls_used,
)
from gnss_cli.solvers.dop import dop_from_cov

__all__ = ["smooth", "smooth_windows", "segment_frame", "finish_smoothing", "Segment", "WindowJob", "distinct_windows",
           "spans_tied", "BATCH_MAX_EPOCHS", "Fit", "fit_all", "framed_segments", "window_jobs", "FALLBACK"]

F64 = NDArray[np.float64]

#: Windows up to this many epochs are fitted together (:mod:`gnss_cli.behavior.batch`, dense
#: per-window factors); longer ones (e.g. ``window=0``) one at a time by the banded O(T) STLS.
BATCH_MAX_EPOCHS = 64
_OK, FALLBACK = EpochStatus.OK.value, EpochStatus.FALLBACK_WLS.value


@dataclass(slots=True)
class Segment:
    """A run of epochs in its local ENU frame."""

    epochs: NDArray[np.intp]
    origin: F64
    rot: F64
    w: F64
    cov: F64


@dataclass(slots=True)
class WindowJob:
    """One window of a segment and the epochs whose estimate it supplies (``lo:hi``, segment-local)."""

    segment: int
    window: int
    a: int
    b: int
    lo: int
    hi: int


def distinct_windows(jobs: list[WindowJob]) -> tuple[list[int], NDArray[np.intp]]:
    """The distinct windows among ``jobs`` and which of them each job is.

    Two rejected neighbours split into windows of half their length can both take the same window
    (same segment, start and end), each copy supplying different epochs; it is one window, solved
    once (:mod:`gnss_cli.pipeline.spans`) and counted once in the cross-fade. Returns the index of
    each distinct window's first job, in order, and for each job the number of its window in that
    list.
    """
    number: dict[tuple[int, int, int], int] = {}
    firsts: list[int] = []
    which = np.empty(len(jobs), dtype=np.intp)
    for k, job in enumerate(jobs):
        key = (job.segment, job.a, job.b)
        if key not in number:
            number[key] = len(firsts)
            firsts.append(k)
        which[k] = number[key]
    return firsts, which


def spans_tied(kinds: frozenset[str]) -> bool:
    """Whether the measurement-domain spans of a run with the measurement ``kinds`` are tied into
    one trajectory (range rates or phase pairs link the epochs across spans,
    :mod:`gnss_cli.pipeline.tied`; each epoch takes one window's estimate). With the pseudoranges
    alone they are not: overlapping windows are cross-faded (:func:`window_weights`), and a
    rejected window's epochs are split into denser windows (:func:`~gnss_cli.pipeline.spans.split_window`)."""
    return kinds != {"pseudorange"}


@dataclass(slots=True)
class Fit:
    """The result of one window: corrected ENU trajectory, kernel, outcome, DOP basis (ENU); for the
    measurement-domain alternation (:mod:`gnss_cli.pipeline.identified`) its iterations, whether it
    converged, the domain of the result (``position``: the STLS of the fixes), its behavior test
    (statistic and degrees of freedom, :func:`~gnss_cli.pipeline.identified.behavior_tests`) and
    whether the test rejected it (:mod:`gnss_cli.pipeline.spans`); the measurement kinds of the
    alternation whose result the window supplies (None: not solved in the measurement domain, or
    not through :func:`~gnss_cli.pipeline.spans.tested_windows`)."""

    w_hat: F64 | None
    kernel: KernelRecord | None
    misfit: float | None
    status: StlsStatus | None
    message: str
    basis: F64 | None
    iterations: int | None = None
    converged: bool | None = None
    domain: str = "position"
    test_stat: float | None = None
    test_dof: int | None = None
    rejected: bool = False
    measurements: frozenset[str] | None = None


def _failed(message: str) -> Fit:
    return Fit(None, None, None, None, message, None)


def _fit_group(segs: list[Segment], jobs: list[WindowJob], lag: int, tol: float, max_iter: int) -> list[Fit]:
    """Identified shared kernels for windows of equal length, all at once."""
    n_t = jobs[0].b - jobs[0].a
    w = np.stack([segs[j.segment].w[j.a : j.b] for j in jobs])
    cov = np.stack([segs[j.segment].cov[j.a : j.b] for j in jobs])
    fits = identify_windows(w, lag, cov, fixed_roots=(1.0,), tol=tol, max_iter=max_iter)
    mis, w_hat, r, status = fits.misfit, fits.w_hat, fits.r, fits.status
    messages = [STATUS_MESSAGES[StlsStatus(int(st))] for st in status]
    ok = np.flatnonzero(status >= 0)
    rec_of = dict(zip(ok.tolist(), shared_kernel_records(r[ok], 3) if ok.size else []))
    basis_of = dict(zip(ok.tolist(), shared_behavior_bases(r[ok], n_t, 3) if ok.size else []))
    out: list[Fit] = []
    for k in range(len(jobs)):
        if status[k] < 0 or basis_of.get(k) is None:
            out.append(_failed(messages[k] if status[k] < 0 else "kernel: R_lag is singular; cannot solve for w(t+lag)"))
            continue
        out.append(Fit(w_hat[k], rec_of[k], float(mis[k]), StlsStatus(int(status[k])), messages[k], basis_of[k]))
    return out


def _fit_single(seg: Segment, job: WindowJob, opts: StlsConfig) -> Fit:
    """One window with the banded per-series path (full kernels and long windows)."""
    w, cov = seg.w[job.a : job.b], seg.cov[job.a : job.b]
    try:
        fixed = (1.0,) if opts.kernel == "shared" else ()
        res = stls(w, opts.lag, opts.full_order, cov, tol=opts.tolerance, max_iter=opts.max_iterations,
                   structure=opts.kernel, fixed_roots=fixed, max_starts=1, restarts=False)
        if res.status < 0:
            raise SingularGramError(res.message)
        ker, m, w_hat, st, message = res.kernel, res.misfit, res.w_hat, res.status, res.message
        basis = behavior_basis(ker.normalized(), job.b - job.a) if ker.p == ker.q else None
    except (GnssError, np.linalg.LinAlgError) as exc:
        return _failed(str(exc))
    return Fit(w_hat, kernel_record(ker), float(m), st, message, basis)


def segment_frame(wls: MethodSolution, epochs: NDArray[np.intp], origin: F64) -> Segment:
    """The epochs ``epochs`` of a segment in the ENU frame at ``origin`` (its first solved fix, m)."""
    lat, lon, _ = ecef2geodetic(origin)
    rot = ecef2enu_rotation(float(lat), float(lon))
    cov_enu = np.einsum("ij,tjk,lk->til", rot, wls.cov_m2[epochs, :3, :3], rot)
    # einsum, not a (T, 3) @ (3, 3) matmul: BLAS rounds a row differently with the number of rows,
    # and the rows must not depend on the number of epochs a piece holds (pipeline/run.py)
    return Segment(epochs, origin, rot, np.einsum("tj,ij->ti", wls.x_ecef_m[epochs] - origin, rot),
                   0.5 * (cov_enu + cov_enu.transpose(0, 2, 1)))


def framed_segments(data: EpochData, wls: MethodSolution, solved: NDArray[np.bool_], status: NDArray[np.str_],
                     need: int, gap_factor: float, segs: list[Segment]) -> Iterator[tuple[int, int]]:
    """Each segment long enough for a window, appended to ``segs`` in its ENU frame: yields its
    index and length; the epochs of too short segments fall back to WLS."""
    for seg in segments(data.time_gps_s, solved, gap_factor):
        if seg.size < need:
            status[seg] = FALLBACK
            continue
        segs.append(segment_frame(wls, seg, wls.x_ecef_m[seg[0]]))
        yield len(segs) - 1, seg.size


def window_jobs(segment: int, n: int, length: int, step: int | None = None) -> list[WindowJob]:
    """The sliding windows of ``length`` epochs over a segment of ``n`` and the epochs each supplies."""
    bounds, owner = windows(n, length, step)
    edges = np.searchsorted(owner, np.arange(len(bounds) + 1), side="left")  # owner is non-decreasing
    return [WindowJob(segment, wi, a, b, int(edges[wi]), int(edges[wi + 1])) for wi, (a, b) in enumerate(bounds)]


def _schedule(data: EpochData, wls: MethodSolution, solved: NDArray[np.bool_], status: NDArray[np.str_],
              opts: StlsConfig, step: int | None, gap_factor: float) -> tuple[list[Segment], list[WindowJob]]:
    """Segments in their ENU frames and their windows; epochs of too short segments fall back to WLS."""
    segs: list[Segment] = []
    jobs: list[WindowJob] = []
    for si, n in framed_segments(data, wls, solved, status, opts.min_window(), gap_factor, segs):
        jobs += window_jobs(si, n, opts.window, step)
    return segs, jobs


def fit_all(segs: list[Segment], jobs: list[WindowJob], opts: StlsConfig) -> list[Fit]:
    """Every window's fit: equal-length shared-kernel windows batched, the others one at a time."""
    fits: list[Fit | None] = [None] * len(jobs)
    by_length: dict[int, list[int]] = {}
    for k, job in enumerate(jobs):
        if opts.kernel == "full" or job.b - job.a > BATCH_MAX_EPOCHS:
            fits[k] = _fit_single(segs[job.segment], job, opts)
        else:
            by_length.setdefault(job.b - job.a, []).append(k)
    for group in by_length.values():
        batch = _fit_group(segs, [jobs[k] for k in group], opts.lag, opts.tolerance, opts.max_iterations)
        for k, fit in zip(group, batch):
            fits[k] = fit
    assert all(f is not None for f in fits)
    return fits  # type: ignore[return-value]


def smooth(
    data: EpochData,
    wls: MethodSolution,
    config: ProcessingConfig,
    *,
    step: int | None = None,
    gap_factor: float = 1.5,
    method: str = "stls",
    measurements: frozenset[str] | None = None,
    factors: tuple[float, ...] | None = None,
) -> tuple[MethodSolution, tuple[WindowModel, ...]]:
    """The identified Hankel STLS of the per-epoch WLS fixes (``config.stls``, ``lag >= 1``).

    Parameters
    ----------
    data : EpochData
        The prepared epochs (from :func:`gnss_cli.pipeline.load_epochs`).
    wls : MethodSolution
        Per-epoch WLS fixes of ``data`` with covariances ``cov_m2`` (m^2).
    config : ProcessingConfig
        ``config.stls`` (lag >= 1, kernel, order, window, tolerance,
        max_iterations; see ``gnss_cli/configs/default.toml``) and the weights, masks and atmosphere
        models of the clock solve.
    step : int, optional
        Window shift (default ``window // 2``). The window whose centre is nearest an epoch
        supplies it (its status); its position is the cross-fade of the windows over it
        (:func:`smooth_windows`), or, where spans are tied, the supplying span's.
    gap_factor : float
        Segments split where the time step exceeds ``gap_factor`` times the median step,
        and at epochs without a WLS fix (no position or covariance).
    method : str
        Method key written into the result.
    measurements : set of str, optional
        None: the position-domain STLS of the fixes. Else the measurement kinds (``pseudorange``
        and any of ``doppler``, ``phase``) of the measurement-domain alternation that starts from
        it (:func:`gnss_cli.pipeline.identified.alternate_windows`; shared kernels), its spans
        chosen by the behavior test (:func:`gnss_cli.pipeline.spans.tested_windows`) and, with
        range rates or phase, solved together (:func:`gnss_cli.pipeline.tied.tie_spans`).
    factors : tuple of float, optional
        With ``measurements``: the variance factors of the kinds (a whole file's), else estimated on ``data``.

    Returns
    -------
    solution : MethodSolution
        Smoothed positions (ECEF, m), re-estimated clocks (m), estimator covariances
        ``cov_m2`` (ECEF + clock, m^2) and multi-epoch DOPs. Status ``ok`` for smoothed
        epochs, ``fallback_wls`` where a segment is too short (unless a tied run took it in across
        missed epochs) or the window fit failed (the WLS fix, covariance and DOPs are kept), the
        WLS status word elsewhere.
    models : tuple of WindowModel
        One record per window, in time order.

    Raises
    ------
    ConfigError
        Invalid options (:meth:`StlsConfig.validated`).
    UsageError
        ``config.stls.lag`` is 0, or ``wls`` does not match ``data``.

    Notes
    -----
    Each window solves ``min sum_t (w_t - w^_t)^T Sigma_t^{-1} (w_t - w^_t)`` subject to
    ``R H_{l+1}(w^) = 0`` with ``w_t = E (x_t - x_origin)`` the ENU position of the fix and
    ``Sigma_t = E C_t E^T`` its rotated WLS covariance.
    """
    opts = config.stls.validated()
    if opts.lag < 1:
        raise UsageError(f"stls.lag: expected an integer >= 1 for the identified Hankel STLS, received {opts.lag}")
    data = as_wls_used(data, wls)  # its satellites and weights: the clocks and residuals are re-estimated from them
    T = data.time_gps_s.size
    if wls.x_ecef_m.shape != (T, 3):
        raise UsageError(f"wls: expected positions of shape ({T}, 3), received {wls.x_ecef_m.shape}")
    solved = np.isin(wls.status, KEEPS_POSITION) & np.all(np.isfinite(wls.x_ecef_m), axis=1) \
        & np.all(np.isfinite(wls.cov_m2[:, :3, :3].reshape(T, 9)), axis=1)
    status = wls.status.astype("<U24").copy()
    segs, jobs = _schedule(data, wls, solved, status, opts, step, gap_factor)
    fits = fit_all(segs, jobs, opts)
    if measurements is not None:
        # spans and tied import this module; measurements pulls in scipy.stats (not for a default run)
        from gnss_cli.pipeline.measurements import factors_from_totals, free_misfit_totals
        from gnss_cli.pipeline.spans import tested_windows
        from gnss_cli.pipeline.tied import tie_spans

        kinds = frozenset(measurements)
        if factors is None:
            factors = factors_from_totals(free_misfit_totals(data, wls, config, kinds))
        jobs, fits, gated, limits = tested_windows(data, wls, config, segs, jobs, fits, kinds, factors)
        bridged = None
        if spans_tied(kinds):
            short = np.flatnonzero(solved & (status == FALLBACK))  # segments too short for a window
            fits, gated_tied, tied, bridged = tie_spans(data, wls, config, segs, jobs, fits, kinds, factors, short)
            gated = np.where(tied[:, None], gated_tied, gated)
        kept = replace(data, usable=data.usable & ~gated)  # clocks and residuals from the rows used
        sol, models = smooth_windows(kept, wls, config, segs, jobs, status, method, fits=fits, limits=limits,
                                     bridged=bridged, cross_fade=not spans_tied(kinds))
        return replace(sol, excluded=gated if wls.excluded is None else (wls.excluded | gated)), models
    return smooth_windows(data, wls, config, segs, jobs, status, method, fits=fits)


def smooth_windows(data: EpochData, wls: MethodSolution, config: ProcessingConfig, segs: list[Segment],
                   jobs: list[WindowJob], status: NDArray[np.str_], method: str = "stls",
                   segment_ids: list[int] | None = None, fits: list[Fit] | None = None,
                   limits: dict[int, float] | None = None, bridged: F64 | None = None,
                   cross_fade: bool = True) -> tuple[MethodSolution, tuple[WindowModel, ...]]:
    """Fit the windows ``jobs`` of the segments ``segs`` and finish the smoothed solution of
    :func:`smooth` (``status``: the WLS words, ``fallback_wls`` set for too short segments).
    ``segment_ids``: the ``segment`` number of each of ``segs`` in the model records
    (default: its index). ``fits``: the windows' fits when already computed (one per job).
    ``limits``: the behavior test's limit of the tested windows (by job index, :mod:`gnss_cli.pipeline.spans`).
    ``bridged``: ``(T, 3)`` ECEF positions (m, NaN elsewhere) of epochs of too short segments that a tied
    run took in across missed epochs (:func:`~gnss_cli.pipeline.tied.tie_spans`): ``ok``, their clocks
    re-estimated, their covariance and DOPs the WLS ones (no window of theirs has a behavior).
    ``cross_fade``: an epoch's position is the mean of every accepted window's estimate of it, weighted
    by :func:`window_weights` (triangular: most at each window's centre), its covariance and DOPs the
    bound of :func:`_window_gains`; False (spans tied into one trajectory): the estimate of the window
    that supplies it."""
    opts = config.stls
    T = data.time_gps_s.size
    x_s = wls.x_ecef_m.copy()
    smoothed = np.zeros(T, dtype=bool)
    if fits is None:
        fits = fit_all(segs, jobs, opts)

    models: list[WindowModel] = []
    dop_windows: list[DopWindow] = []
    estimates: list[tuple[NDArray[np.intp], F64, F64]] = []  # (window epochs, ECEF positions, weights)
    counted = set(distinct_windows(jobs)[0])  # a window's first copy: a window counts once in the cross-fade
    limits = limits or {}
    for k, (job, fit) in enumerate(zip(jobs, fits)):
        seg = segs[job.segment]
        mine = seg.epochs[job.lo : job.hi]
        models.append(WindowModel(
            segment=job.segment if segment_ids is None else segment_ids[job.segment], window=job.window,
            start_time_gps_s=float(data.time_gps_s[seg.epochs[job.a]]),
            end_time_gps_s=float(data.time_gps_s[seg.epochs[job.b - 1]]), n_epochs=int(job.b - job.a),
            model="identified", structure=opts.kernel, kernel=fit.kernel, misfit=fit.misfit,
            status=WINDOW_REJECTED if fit.rejected else window_status_word(fit.status), message=fit.message,
            method=method, iterations=fit.iterations, converged=fit.converged, test_stat=fit.test_stat,
            test_dof=fit.test_dof, test_limit=limits.get(k), n_supplied=int(mine.size),
            supplied_start_time_gps_s=float(data.time_gps_s[mine[0]]) if mine.size else None,
            supplied_end_time_gps_s=float(data.time_gps_s[mine[-1]]) if mine.size else None,
        ))
        status[mine] = window_epoch_status(fit.status if fit.w_hat is not None else None).value
        if fit.w_hat is None:
            continue
        smoothed[mine] = True
        weights = window_weights(job, cross_fade) if k in counted or not cross_fade else np.zeros(job.b - job.a)
        estimates.append((seg.epochs[job.a : job.b], seg.origin + np.einsum("tj,ji->ti", fit.w_hat, seg.rot), weights))
        has_basis = fit.basis is not None and fit.basis.shape[2] > 0
        dop_windows.append(DopWindow(seg.epochs[job.a : job.b], np.einsum("ji,tjk->tik", seg.rot, fit.basis)
                                     if has_basis else None, weights))
    x_s[smoothed] = blended(T, estimates)[smoothed]
    if bridged is not None:
        took = np.all(np.isfinite(bridged), axis=1)
        x_s[took], status[took], smoothed[took] = bridged[took], _OK, True
    sol = finish_smoothing(data, wls, config, x_s, status, smoothed, dop_windows, method)
    sol, no_paper_gdop = with_paper_gdop(sol, segs, jobs, fits, opts.lag, opts.kernel)
    for k, why in no_paper_gdop.items():  # the window's record says why its epochs have no gdop_paper
        models[k] = replace(models[k], message=f"{models[k].message}; no paper STLS GDOP: {why}")
    return sol, tuple(models)


class DopWindow(NamedTuple):
    """A window's share of the multi-epoch covariances and DOPs: its epochs, its behavior's ECEF
    basis ``(N, 3, k)`` (None: the window has none) and the weight ``(N,)`` its estimate has in
    each epoch's (:func:`window_weights`)."""

    span: NDArray[np.intp]
    basis: F64 | None
    weights: F64


def window_weights(job: WindowJob, cross_fade: bool) -> F64:
    """The weights ``(b - a,)`` of a window's estimate of its epochs.

    ``cross_fade``: triangular, ``min(i + 1, N - i)`` at the window's ``i``-th of ``N`` epochs, so
    that overlapping windows fade into each other and each counts most at its centre; else 1 at
    the epochs the window supplies (``lo:hi``, those nearest its centre) and 0 elsewhere.
    """
    n = job.b - job.a
    if cross_fade:
        i = np.arange(n)
        return np.minimum(i + 1, n - i).astype(np.float64)
    out = np.zeros(n)
    out[job.lo - job.a : job.hi - job.a] = 1.0
    return out


def blended(T: int, estimates: list[tuple[NDArray[np.intp], F64, F64]]) -> F64:
    """``(T, 3)`` weighted means of the windows' estimates ``(epochs, (N, 3) positions, (N,) weights)``
    of each epoch (NaN where no window has weight)."""
    total, weight = np.zeros((T, 3)), np.zeros(T)
    for span, x, w in estimates:
        total[span] += w[:, None] * x
        weight[span] += w
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(weight[:, None] > 0, total / weight[:, None], np.nan)


def finish_smoothing(data: EpochData, wls: MethodSolution, config: ProcessingConfig, x_s: F64, status: NDArray[np.str_],
            smoothed: NDArray[np.bool_], dop_windows: list[DopWindow], method: str) -> MethodSolution:
    """The smoothed MethodSolution: clocks re-estimated, multi-epoch covariances and DOPs."""
    T = data.time_gps_s.size
    clocks = wls.clocks_m.copy()
    n_clk = clocks.shape[1]
    out = {"cov": wls.cov_m2.copy(), "residuals": wls.residuals_m.copy(), "n_sat": wls.n_sat.copy(),
           "tdops": wls.tdops.copy() if wls.tdops is not None else None}
    dops = {k: getattr(wls, k).copy() for k in ("gdop", "pdop", "hdop", "vdop", "tdop")}
    rows = np.flatnonzero(smoothed)
    if rows.size:
        geometry, rot_local, present = _reestimate_clocks(data, config, rows, x_s, clocks, out)
        gain_q = _window_gains(T, n_clk, dop_windows, geometry, out["cov"], smoothed)
        _multi_epoch_dops(gain_q, rot_local, present, n_clk, dops, out["tdops"])
    bad = np.isin(status, [_OK, FALLBACK], invert=True)
    x_out = np.where(bad[:, None], np.nan, x_s)
    clocks = np.where(bad[:, None], np.nan, clocks)
    return replace(wls, method=method, x_ecef_m=x_out, clocks_m=clocks, tdops=out["tdops"], n_sat=out["n_sat"],
                   cov_m2=np.where(bad[:, None, None], np.nan, out["cov"]), status=status,
                   residuals_m=np.where(bad[:, None], np.nan, out["residuals"]), gdop_paper=None, **dops)


def _reestimate_clocks(data: EpochData, config: ProcessingConfig, rows: NDArray[np.intp], x_s: F64, clocks: F64,
                       out: dict) -> tuple[dict[str, tuple[F64, F64, F64]], F64, NDArray[np.bool_]]:  # type: ignore[type-arg]
    """Clocks, residuals and satellites of the smoothed epochs ``rows`` (in place), and their geometry.

    Returns the per-epoch clock-reduced information (weighted ``"w"`` and unit ``"u"``, see
    :func:`~gnss_cli.behavior.multi_epoch.epoch_information`), the ENU rotations and which
    systems have satellites.
    """
    T, n = data.time_gps_s.size, data.sv.size
    n_clk = clocks.shape[1]
    present = np.ones((T, n_clk), dtype=bool)
    # One clock per system: rows [satellites (n), constraints of absent systems (k > 1)].
    lin = linearize(data, rows, x_s[rows], np.zeros((rows.size, n_clk)), config)
    clock_cols = lin.A[..., 3:]
    wgt = np.where(lin.mask, 1.0 / lin.var_m2, 0.0)
    sw = np.einsum("tn,tnk->tk", wgt, clock_cols)
    clocks[rows] = np.einsum("tn,tnk,tn->tk", wgt, clock_cols, lin.q) / np.where(sw > 0, sw, 1.0)
    fitted = lin.q - np.einsum("tnk,tk->tn", clock_cols, clocks[rows])
    out["residuals"][rows] = np.where(lin.mask[:, :n], fitted[:, :n], np.nan)
    out["n_sat"][rows] = lin.mask[:, :n].sum(axis=1)
    if n_clk > 1:
        present[rows] = ~lin.mask[:, n:]  # a set constraint row marks a system without satellites
    p_m = lin.A[..., :3]
    sat_rows = lin.mask.astype(np.float64)
    sat_rows[:, n:] = 0.0  # the DOP gain is from satellite noise only, as for the snapshot methods
    geometry = {}
    for name, weights in (("w", wgt), ("u", sat_rows)):
        info, h, cv = np.full((T, 3, 3), np.nan), np.full((T, n_clk, 3), np.nan), np.full((T, n_clk), np.nan)
        info[rows], h[rows], cv[rows] = epoch_information(p_m, weights, clock_cols)
        geometry[name] = (info, h, cv)
    rot_local = np.full((T, 3, 3), np.nan)
    rot_local[rows] = lin.rot
    return geometry, rot_local, present


def _window_gains(T: int, n_clk: int, dop_windows: list[DopWindow], geometry: dict[str, tuple[F64, F64, F64]],
                  cov: F64, smoothed: NDArray[np.bool_]) -> F64:
    """Multi-epoch covariances into ``cov`` (in place) and the unit-weight gains ``(T, 3+k, 3+k)`` of
    the ``smoothed`` epochs.

    An epoch's are the weighted means of the covariances (gains) its windows' estimates have there,
    with the weights of :func:`blended`: for weights that sum to 1 the mean of the covariances bounds
    the covariance of the mean of the estimates, however they correlate (for every direction ``u``,
    ``(sum a_i u.e_i)^2 <= sum a_i (u.e_i)^2``). An epoch with a window whose covariance is
    singular, or no behavior basis, keeps the WLS covariance and DOPs.
    """
    size = 3 + n_clk
    acc_cov, acc_gain = np.zeros((T, size, size)), np.zeros((T, size, size))
    weight, missing = np.zeros(T), np.zeros(T, dtype=bool)
    groups: dict[tuple[int, int], list[int]] = {}
    for j, win in enumerate(dop_windows):
        if win.basis is None:
            missing[win.span[win.weights > 0]] = True
        else:
            groups.setdefault(win.basis.shape[::2], []).append(j)
    for members in groups.values():
        spans = np.stack([dop_windows[j].span for j in members])
        bases = np.stack([dop_windows[j].basis for j in members])
        cw = window_covs(bases, spans, *geometry["w"])
        cu = window_covs(bases, spans, *geometry["u"])
        for i, j in enumerate(members):
            span, _, w = dop_windows[j]
            if cw[i] is None or cu[i] is None:
                missing[span[w > 0]] = True
                continue
            acc_cov[span] += w[:, None, None] * cw[i]
            acc_gain[span] += w[:, None, None] * cu[i]
            weight[span] += w
    have = smoothed & (weight > 0) & ~missing
    gain_q = np.full((T, size, size), np.nan)
    cov[have] = acc_cov[have] / weight[have, None, None]
    gain_q[have] = acc_gain[have] / weight[have, None, None]
    return gain_q


def _multi_epoch_dops(gain_q: F64, rot_local: F64, present: NDArray[np.bool_], n_clk: int,
                      dops: dict[str, F64], tdops: F64 | None) -> None:
    """DOPs (in place) of the epochs with a multi-epoch gain."""
    T = gain_q.shape[0]
    have = np.flatnonzero(np.all(np.isfinite(gain_q.reshape(T, -1)), axis=1))
    if not have.size:
        return
    d = dop_from_cov(gain_q[have], rot_local[have])
    for k in dops:
        dops[k][have] = getattr(d, k)
    dops["tdop"][have] = np.where(present[have, 0], dops["tdop"][have], np.nan)
    if tdops is not None:
        q_clk = gain_q[have][:, 3 + np.arange(n_clk), 3 + np.arange(n_clk)]
        tdops[have] = np.where(present[have], np.sqrt(np.clip(q_clk, 0.0, None)), np.nan)
